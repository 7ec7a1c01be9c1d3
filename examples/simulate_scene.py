"""Simulate a layered scene
========================

Simulate a layered preset scene into an impulse dataset by Monte Carlo, then describe it.

Run ``python examples/simulate_scene.py [OUT_FOLDER]``.

A 16 x 16 grid with 400 photons per lit point and channel takes a few seconds.
"""

import sys
import tempfile
from pathlib import Path

from ringlight.core import open_dataset
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.transport import simulate_transport, write_transport

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="ringlight-example-")) / "layers3"
scene = load_scene("layers3", size=(16, 16))  # shapes and layers scale with the grid
transport = simulate_transport(scene, photons=400, seed=1)
folder = write_transport(transport, out)
dataset = open_dataset(folder)
print(f"wrote {folder}")
print(f"grid {dataset.grid_shape[0]} x {dataset.grid_shape[1]}, {len(dataset.manifest.frames)} frames, "
      f"max_radius {dataset.max_radius:g}")
for layer in dataset.manifest.ground_truth.layers:
    print(f"layer {layer.name}: depth {layer.depth[0]:g}-{layer.depth[1]:g}, "
          f"rgb {' '.join(f'{v:.4f}' for v in layer.rgb)}")
