"""Benchmark of the layer inversion's time (not a test: prints figures and ratios to the targets).

On the bundled ``layers3`` sample (48 x 48, all pixels): the white Monte Carlo databases are made
first (their time printed, then cached, as in use); then, timed, a known-structure fit (boundaries
2, 5 and the scene's scattering per layer; target <= 10 s) and a structure search (1 to 4 layers by
BIC, boundaries and the scattering searched, common or with a base of its own; target <= 120 s,
timed the second time, once its databases are cached). ``tools/evaluate_inversion.py`` has the
accuracy of both on every layered scene.

    python benchmarks/bench_inversion.py
"""

from __future__ import annotations

import time

import numpy as np
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.inversion.layers import database_optics
from ringlight.core.inversion.settings import MUS_GRID, SEARCH_BINS, InversionSettings
from ringlight.core.inversion.report import invert_region
from ringlight.core.inversion.white_mc import white_database
from ringlight.core.simulate.samples import sample_dataset

KNOWN_TARGET_S = 10.0
SEARCH_TARGET_S = 120.0


def timed(dataset, settings):
    region = np.ones(dataset.grid_shape, bool)
    start = time.perf_counter()
    result = invert_region(dataset, region, "all pixels", settings)
    return result, time.perf_counter() - start


def report(label, result, seconds, target):
    errors = ", ".join(f"{e:.3f}" for e in result.errors) if result.errors is not None else "n/a (layer count differs)"
    flags = ", ".join("yes" if layer.determined else "no" for layer in result.inversion.layers)
    print(f"{label}: {seconds:.1f} s (target {target:g} s, ratio {seconds / target:.2f}); "
          f"{result.inversion.notes}; chi2/dof {result.inversion.chi2_per_dof:.2f}; xy errors {errors}; "
          f"determined {flags}", flush=True)


def main() -> None:
    dataset = open_dataset(sample_dataset("layers3"))
    known = InversionSettings(3, (2, 5), (0.5, 0.5, 1.5), 1.3, 0.0, 24.0)
    search = InversionSettings(None, None, None, 1.3, 0.0, 24.0)
    start = time.perf_counter()
    white_database(database_optics(known, known.mus), known.photons)
    for mus in MUS_GRID:
        white_database(database_optics(search, mus), search.photons)
    print(f"white databases: {1 + len(MUS_GRID)} of {known.photons} photons ({SEARCH_BINS} depth bins for the "
          f"search), {time.perf_counter() - start:.1f} s (once; cached in the user cache)", flush=True)
    report("layers3, known structure", *timed(dataset, known), KNOWN_TARGET_S)
    # A search also makes the databases of a base that scatters otherwise (cached as it goes): the
    # first search pays for them once, the second is timed as in use.
    _, seconds = timed(dataset, search)
    print(f"first structure search, making its base databases: {seconds:.1f} s", flush=True)
    report("layers3, structure search (1-4 layers, scattering common or the base's own)", *timed(dataset, search),
           SEARCH_TARGET_S)


if __name__ == "__main__":
    main()
