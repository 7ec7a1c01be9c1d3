"""Evaluate layer colour recovery on layered scenes: the paper's and the radiance method against the
inverse method (known structure, and a structure search: boundaries and scattering, common or with
a base of its own).

Each scene is simulated by ringlight's own simulator (reference estimator) at SIZE x SIZE with its
photons per point times each --scale, written as a dataset and read back; the methods see only the
dataset (the inverse method is also told n, g, the depth and, for the known structure, the layer
boundaries and scattering coefficients of the scene). Prints one markdown row per scene, scale,
method and layer: xy error to the truth (FORMAT.md's thick-slab colour), whether the layer is
determined (paper/radiance: trusted), the width of its two-sigma region, whether the truth lies in
it, and the fit's time and chi-square.

    python tools/evaluate_inversion.py [--size 24] [--scale 1 10] [SCENE ...]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ringlight.core.colour.layer_report import analyse_layers
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.inversion.report import invert_region
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.transport import simulate_transport, write_transport

SCENES = ("layers3", "layers-thick", "layers-reversed", "layers2", "layers-mus")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scenes", nargs="*", default=list(SCENES))
    parser.add_argument("--size", type=int, default=24)
    parser.add_argument("--scale", type=float, nargs="+", default=[1.0, 10.0])
    args = parser.parse_args()
    print("| scene | photons/point | method | layer | xy error | determined | 2-sigma width | truth inside | "
          "fit s | chi2/dof |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.scenes:
        scene = load_scene(name, size=(args.size, args.size))
        materials = {material.name: material for material in scene.materials}
        boundaries = tuple(int(round(top)) for _, top, _ in scene.layers[1:])
        mus = tuple(float(materials[layer].mus[0]) for layer, _, _ in scene.layers)
        g = materials[scene.layers[0][0]].g
        for scale in args.scale:
            photons = int(scene.photons_per_point * scale)
            with tempfile.TemporaryDirectory() as folder:
                write_transport(simulate_transport(scene, photons), Path(folder) / "ds")
                dataset = open_dataset(Path(folder) / "ds")
                region = np.ones(dataset.grid_shape, bool)
                count = len(scene.layers)
                for method in ("paper", "radiance"):
                    start = time.perf_counter()
                    analysis = analyse_layers(dataset, region, "all pixels", auto=count, method=method)
                    seconds = time.perf_counter() - start
                    result = analysis.result
                    for index, layer in enumerate(result.layers):
                        error = result.errors[index] if result.errors is not None else float("nan")
                        print(f"| {name} | {photons} | {method} | {index + 1} | {error:.3f} | "
                              f"{'trusted' if layer.trusted else 'untrusted'} | - | - | {seconds:.1f} | - |",
                              flush=True)
                runs = [("inverse, known structure", InversionSettings(count, boundaries, mus if len(set(mus)) > 1
                                                                       else mus[0], scene.n, g, scene.depth)),
                        ("inverse, searched", InversionSettings(count, None, None, scene.n, g,
                                                                             scene.depth))]
                for label, settings in runs:
                    result = invert_region(dataset, region, "all pixels", settings)
                    inversion = result.inversion
                    for index, layer in enumerate(inversion.layers):
                        width = np.ptp(layer.region, axis=0).max() if len(layer.region) else float("nan")
                        error = result.errors[index] if result.errors is not None else float("nan")
                        inside = result.inside[index] if result.inside is not None else None
                        print(f"| {name} | {photons} | {label} | {index + 1} | {error:.3f} | "
                              f"{'yes' if layer.determined else 'no'} | {width:.3f} | "
                              f"{'yes' if inside else 'no'} | {inversion.seconds:.1f} | "
                              f"{inversion.chi2_per_dof:.2f} |", flush=True)
                    if label.endswith("searched"):
                        print(f"|  |  | ({inversion.notes}) |  |  |  |  |  |  |  |", flush=True)
    sys.exit(0)


if __name__ == "__main__":
    main()
