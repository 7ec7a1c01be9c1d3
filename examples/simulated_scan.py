"""A whole capture with the simulated rig
======================================

Gray code, plan, HDR scan, then open the dataset: the same steps as the Capture tab and
``ringlight capture``, on a 12 x 12 virtual projector. Run
``python examples/simulated_scan.py [OUT_FOLDER]``.
"""

import sys
import tempfile
from pathlib import Path

from ringlight.core import open_dataset
from ringlight.core.capture.hardware import discover_plugins, make_device
from ringlight.core.capture.scan import Scan
from ringlight.core.capture.workflow import (
    camera_notes,
    measure_correspondence,
    plan_scan,
    run_scan,
)

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="ringlight-example-")) / "scan"
discovery = discover_plugins()  # built-in and installed hardware plugins
options = {"size": "12x12", "photons": "300"}
camera = make_device(discovery.cameras(), "simulated", options)
projector = make_device(discovery.projectors(), "simulated", options)
camera.open(), projector.open()
try:
    correspondence = measure_correspondence(camera, projector)
    planned = plan_scan(camera, projector, correspondence, (0, 0, 12, 12), max_radius=3.0)
    scan = Scan(out, planned.plan, planned.mapping, camera_notes(camera))
    folder = run_scan(scan, camera, projector, False)
finally:
    projector.close(), camera.close()
dataset = open_dataset(folder)
print(f"wrote {folder}: {len(dataset.manifest.frames)} frames for a "
      f"{dataset.grid_shape[0]} x {dataset.grid_shape[1]} grid, {dataset.missing_count} points missing")
