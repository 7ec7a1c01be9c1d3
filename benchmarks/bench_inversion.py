"""Benchmark of the layer inversion's time (not a test: prints figures and ratios to the targets).

On the bundled ``layers3`` sample (48 x 48, all pixels, 8 replicates, simulated at n 1.3): the white
Monte Carlo databases are made first (their time printed, then cached, as in use); then, timed, a
known-structure fit (boundaries 2, 5 and the scene's scattering per layer, n as the dataset states;
target <= 10 s) and a full search (1 to 4 layers by BIC, boundaries, the scattering, common or with
a base of its own, and the refractive index from 1, 1.33, 1.4, 1.5; target <= 120 s, timed the
second time, once its databases are cached). Each result's layers print their xy error, region
width and the width the data allow. ``tools/evaluate_inversion.py`` and ``tools/evaluate_index.py``
have the accuracy on other scenes.

    python benchmarks/bench_inversion.py
"""

from __future__ import annotations

import time

import numpy as np
from ringlight.core.colour.chroma import chromaticity
from ringlight.core.colour.layer_report import truth_layers
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.inversion.layers import database_optics, invert
from ringlight.core.inversion.measured import measured_profile
from ringlight.core.inversion.report import profile_radii
from ringlight.core.inversion.settings import MUS_GRID, N_GRID, SEARCH_BINS, InversionSettings
from ringlight.core.inversion.white_mc import white_database
from ringlight.core.simulate.samples import sample_dataset

KNOWN_TARGET_S = 10.0
SEARCH_TARGET_S = 120.0


def timed(measured, settings):
    start = time.perf_counter()
    inversion = invert(measured, settings)
    return inversion, time.perf_counter() - start


def report(label, inversion, seconds, target, truth_xy):
    layers = "; ".join(
        f"{index + 1}: error {np.hypot(*(layer.xy - truth_xy[index])):.4f}, width {layer.region_width:.3f}, "
        f"data allow {layer.allowed_width:.3f}{'' if layer.determined else ' (not determined)'}"
        if index < len(truth_xy) else f"{index + 1}: no truth layer"
        for index, layer in enumerate(inversion.layers))
    print(f"{label}: {seconds:.1f} s (target {target:g} s, ratio {seconds / target:.2f}); {inversion.notes}; "
          f"chi2/dof {inversion.chi2_per_dof:.2f}; {layers}", flush=True)


def main() -> None:
    dataset = open_dataset(sample_dataset("layers3"))
    measured = measured_profile(dataset, np.ones(dataset.grid_shape, bool), profile_radii(dataset))
    truth_xy = chromaticity(truth_layers(dataset)[1], dataset.colorspace)
    known = InversionSettings(3, (2, 5), (0.5, 0.5, 1.5), 1.3, 0.0, 24.0)
    search = InversionSettings(None, None, None, None, 0.0, 24.0)
    start = time.perf_counter()
    white_database(database_optics(known, known.mus), known.photons)
    for n in N_GRID:
        for mus in MUS_GRID:
            white_database(database_optics(search, mus, n), search.photons)
    print(f"white databases: {1 + len(MUS_GRID) * len(N_GRID)} of {known.photons} photons ({SEARCH_BINS} depth "
          f"bins for the search), {time.perf_counter() - start:.1f} s (once; cached in the user cache)", flush=True)
    report("layers3, known structure and index", *timed(measured, known), KNOWN_TARGET_S, truth_xy)
    # A search also makes the databases of a base that scatters otherwise (cached as it goes): the
    # first search pays for them once, the second is timed as in use.
    _, seconds = timed(measured, search)
    print(f"first full search, making its base databases: {seconds:.1f} s", flush=True)
    report("layers3, full search (1-4 layers, boundaries, scattering common or the base's own, index)",
           *timed(measured, search), SEARCH_TARGET_S, truth_xy)


if __name__ == "__main__":
    main()
