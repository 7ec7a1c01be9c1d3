"""A transient image of the demo
=============================

Open the bundled demo dataset and save its transient image T_r at r = 2 as a PNG.

Run ``python examples/open_demo_save_transient.py [OUT_FOLDER]``.

The demo (the bundled red-bead sample, 48 x 48) is written into the user cache on first use.
"""

import sys
import tempfile
from pathlib import Path

from ringlight.core import open_dataset, transient_stack
from ringlight.core.colour.display import DisplaySettings, display_levels, render
from ringlight.core.colour.image_export import write_png
from ringlight.core.simulate.samples import ensure_demo_dataset

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="ringlight-example-"))
dataset = open_dataset(ensure_demo_dataset())
stack = transient_stack(dataset, [2.0], step=1.0)  # T_2 = E_2 - E_3
image = stack.images[0]  # (H, W, 3) linear radiance, NaN where undefined
settings = DisplaySettings()  # per-image 99.5th percentile, as the paper displays transients
pixels = render(image, display_levels(image, settings), settings, dataset.colorspace)
path = write_png(out / "transient_r2.png", pixels)
print(f"wrote {path}: {pixels.shape[1]} x {pixels.shape[0]} pixels of T_r at r = 2")
