"""Layer colours of a region
=========================

Recover the layer colours of a rectangular region from transient images at three radii.

Run ``python examples/layer_colours.py [DATASET]``.

Without DATASET, the layers3 preset is simulated at 16 x 16 into a temp folder first.
"""

import sys
import tempfile
from pathlib import Path

from ringlight.core import open_dataset
from ringlight.core.colour.layer_report import analyse_layers
from ringlight.core.colour.regions import rectangle_region
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.transport import simulate_transport, write_transport

if len(sys.argv) > 1:
    source = Path(sys.argv[1])
else:
    source = Path(tempfile.mkdtemp(prefix="ringlight-example-")) / "layers3"
    write_transport(simulate_transport(load_scene("layers3", size=(16, 16)), photons=400, seed=1), source)
dataset = open_dataset(source)
print(f"dataset {source}")
height, width = dataset.grid_shape
region = rectangle_region(dataset.grid_shape, 2, 2, height - 2, width - 2)  # y0, x0, y1, x1 (end exclusive)
analysis = analyse_layers(dataset, region, "centre", radii=[1.0, 3.0, 5.0], method="paper")
result = analysis.result
for index, layer in enumerate(result.layers):
    line = f"layer {index + 1} r {layer.radius:g} xy {layer.xy[0]:.4f} {layer.xy[1]:.4f}"
    if result.truth_xy is not None and index < len(result.truth_xy):  # presets carry their true layers
        true_x, true_y = result.truth_xy[index]
        line += f" truth {analysis.truth_names[index]} xy {true_x:.4f} {true_y:.4f} error {result.errors[index]:.4f}"
    print(line)
