"""What a region's ring-light profile can tell about layer colours at best: the inverse method fitted
to a profile without error.

For each layered scene the forward model (:class:`ringlight.core.inversion.forward.Forward`, the
scene's known structure and scattering, a white database of ``--photons``) makes the profile
E_c(r) at the scene's true absorption, r = 0 .. ``--radius``, and the inversion fits it with a
standard error of ``--noise`` times E per ring. The model is then exact and the profile has no
error, so what is left of each layer's two-sigma region (and of its xy distance to the truth, the
thick-slab colour of FORMAT.md) is set by the information the profile holds at that noise and by
the white run's own noise alone: no method fitting E(r) alone can be surer. The noise is known, so
the fit's relative floor for noise a dataset does not show is 0.

Prints one markdown row per scene, noise and layer: the truth's and the fit's absorption per
channel with its two-sigma range, the layer's xy error, its region's width and the width the data
alone allow (:mod:`ringlight.core.inversion.limit`: the Fisher information at the data's noise,
without the white run's): their ratio is what the white run's noise costs.

    python tools/inversion_limit.py [--noise 0.01 0.001] [--photons 20000] [--radius 11] [--reach 13] [SCENE ...]
"""

from __future__ import annotations

import argparse

import numpy as np

from ringlight.core.colour.chroma import chromaticity
from ringlight.core.inversion import layers, search
from ringlight.core.inversion.forward import Forward, Structure
from ringlight.core.inversion.layers import invert
from ringlight.core.inversion.measured import MeasuredProfile
from ringlight.core.inversion.search import database_optics
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.inversion.white_mc import white_database
from ringlight.core.simulate.adding_doubling import thick_slab_reflectance
from ringlight.core.simulate.presets import load_scene

SCENES = ("layers3", "layers-thick", "layers-reversed", "layers2", "layers-mus")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scenes", nargs="*", default=list(SCENES))
    parser.add_argument("--noise", type=float, nargs="+", default=[0.01, 0.001],
                        help="relative standard error of each ring's E (default 0.01 0.001)")
    parser.add_argument("--photons", type=int, default=20_000, help="photons of the white database")
    parser.add_argument("--radius", type=int, default=11, help="largest ring radius (11: a 24 px sample's)")
    parser.add_argument("--reach", type=int, default=search.REACH,
                        help=f"pixels around the lit point the white databases keep (default {search.REACH}; "
                             "at least --radius)")
    args = parser.parse_args()
    if args.reach < args.radius:
        parser.error(f"--reach {args.reach} must be at least --radius {args.radius}")
    layers.REACH = search.REACH = args.reach  # the search's optics and the inversion's check
    print("| scene | noise | layer | truth mua R, G, B | fitted mua [two-sigma range] R; G; B | xy error | "
          "2-sigma width | data allow |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.scenes:
        scene = load_scene(name)
        materials = {material.name: material for material in scene.materials}
        boundaries = tuple(int(round(top)) for _, top, _ in scene.layers[1:])
        mus = tuple(float(materials[layer].mus[0]) for layer, _, _ in scene.layers)
        g = materials[scene.layers[0][0]].g
        truth = np.array([materials[layer].mua for layer, _, _ in scene.layers], np.float64)  # (L, 3)
        settings = InversionSettings(len(mus), boundaries, mus if len(set(mus)) > 1 else mus[0], scene.n, g,
                                     scene.depth, args.photons)
        optics = database_optics(settings, settings.mus)
        forward = Forward(white_database(optics, args.photons), Structure((0, *boundaries)),
                          np.arange(args.radius + 1.0))
        profile = np.stack([forward.profile(truth[:, c]) for c in range(3)], axis=1)  # (R, 3)
        truth_xy = chromaticity(np.array([thick_slab_reflectance(np.full(3, m), row, g, scene.n)
                                          for m, row in zip(mus, truth)]), "sRGB")
        for noise in args.noise:
            measured = MeasuredProfile(forward.radii, profile, noise * profile, points=2, floor=0.0)
            inversion = invert(measured, settings)
            for index, layer in enumerate(inversion.layers):
                ranges = "; ".join(f"{m:.4f} [{low:.4f}, {high:.4g}]"
                                   for m, (low, high) in zip(layer.mua, layer.mua_interval))
                error = float(np.hypot(*(layer.xy - truth_xy[index])))
                print(f"| {name} | {noise:g} | {index + 1}{'' if layer.determined else '*'} | "
                      f"{', '.join(f'{m:g}' for m in truth[index])} | {ranges} | {error:.3f} | "
                      f"{layer.region_width:.3f} | {layer.allowed_width:.3f} |", flush=True)


if __name__ == "__main__":
    main()
