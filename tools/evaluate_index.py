"""Evaluate the inverse method as a user runs it on a held-out three-layer slab of known truth, at
refractive index 1 and 1.4: ``--layers 3``, the boundaries, the scattering and the index searched;
and with the structure and scattering given, the index searched.

The slab (:data:`SLAB`, not a bundled preset) is simulated by ringlight's simulator in independent
replicates (its data noise measured), written as a dataset whose manifest does not state its
index (the ``sample`` key is removed, as for a capture of unknown material), read back, and the
whole grid's profile inverted. Prints one markdown row per index and layer: the xy error to the
truth (FORMAT.md's thick-slab colour), the region's width and the width the data allow, whether
the layer is determined and whether the truth lies in its region; then the model chosen and the
time. The slab's layers scatter as ``--mus TOP BASE`` (the two upper layers alike; 1 and 2 by
default, values the search tries; 0.8 and 1.2 lie between them).

    python tools/evaluate_index.py [--size 24] [--photons 4000] [--replicates 8] [--index 1 1.4] [--mus 1 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.inversion.report import invert_region
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.simulate.replicates import simulate_replicates
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import write_transport

SLAB = {
    "format": "ringlight-scene", "version": 1, "grid": {"height": 24, "width": 24}, "depth": 24, "n": 1.0,
    "materials": {
        "cyan": {"mus": [1.0, 1.0, 1.0], "mua": [0.25, 0.02, 0.01]},
        "amber": {"mus": [1.0, 1.0, 1.0], "mua": [0.005, 0.08, 0.3]},
        "rose": {"mus": [2.0, 2.0, 2.0], "mua": [0.02, 0.2, 0.08]},
    },
    "background": "rose",
    "layers": [{"material": "cyan", "top": 0.0, "bottom": 2.0}, {"material": "amber", "top": 2.0, "bottom": 5.0}],
    "photons_per_point": 4000, "max_radius": 12, "path_length_bins": {"step": 1.0, "count": 32}, "seed": 7,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=24)
    parser.add_argument("--photons", type=int, default=4000)
    parser.add_argument("--replicates", type=int, default=8)
    parser.add_argument("--index", type=float, nargs="+", default=[1.0, 1.4])
    parser.add_argument("--mus", type=float, nargs=2, default=[1.0, 2.0])
    args = parser.parse_args()
    top, base = args.mus
    materials = {name: {**material, "mus": [base if name == "rose" else top] * 3}
                 for name, material in SLAB["materials"].items()}
    print("| n | fit | layer | xy error | region width | data allow | determined | truth inside |")
    print("|---|---|---|---|---|---|---|---|")
    runs = [("searched", InversionSettings(layers=3, depth=24.0)),
            ("known structure", InversionSettings(3, (2, 5), (top, top, base), None, 0.0, 24.0))]
    for n in args.index:
        document = {**SLAB, "n": n, "grid": {"height": args.size, "width": args.size}, "materials": materials}
        scene = parse_scene(document, name="held-out slab")
        transport = simulate_replicates(scene, args.photons, args.replicates)
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "slab"
            write_transport(transport, path)
            manifest = json.loads((path / "dataset.json").read_text())
            del manifest["sample"]  # a capture of unknown material
            (path / "dataset.json").write_text(json.dumps(manifest))
            dataset = open_dataset(path)
            for label, settings in runs:
                result = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels", settings)
                inversion = result.inversion
                for index, layer in enumerate(inversion.layers):
                    print(f"| {n:g} | {label} | {index + 1} | {result.errors[index]:.4f} | {layer.region_width:.4f} | "
                          f"{layer.allowed_width:.4f} | {'yes' if layer.determined else 'no'} | "
                          f"{'yes' if result.inside[index] else 'no'} |", flush=True)
                print(f"| n {n:g}, {label}: {inversion.notes}; chi-square {inversion.chi2:.1f} for {inversion.dof}; "
                      f"{inversion.seconds:.0f} s |  |  |  |  |  |  |  |", flush=True)
    sys.exit(0)


if __name__ == "__main__":
    main()
