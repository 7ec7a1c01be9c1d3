"""Export a transient stack as EXR
===============================

Compute a transient stack of a dataset and export it as EXR (the stack export of docs/format/stack.md).

Run ``python examples/export_stack.py [DATASET] [OUT_FOLDER]``.

DATASET defaults to the bundled demo dataset; OUT_FOLDER must be new (default: a temp folder).
"""

import sys
import tempfile
from pathlib import Path

from ringlight.core import (
    open_dataset,
    radius_range,
    read_stack,
    transient_stack,
    write_stack,
)
from ringlight.core.simulate.samples import ensure_demo_dataset

source = Path(sys.argv[1]) if len(sys.argv) > 1 else ensure_demo_dataset()
out = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tempfile.mkdtemp(prefix="ringlight-example-")) / "stack"
dataset = open_dataset(source, radius=7.0)  # keep responses up to the largest r + dr
stack = transient_stack(dataset, radius_range(0, 6, 1), step=1.0)
folder = write_stack(stack, out)
document, images = read_stack(folder)  # read back what was written
print(f"wrote {folder}")
print("radii", " ".join(f"{r:g}" for r in document["radii"]))
print("shape", " ".join(str(n) for n in images.shape))
