"""Benchmark of the layer inversion's time (not a test: prints figures and ratios to the targets).

First a white run of 2 000 000 photons for layers3's three-layer structure, tallied in cells
(:mod:`ringlight.core.inversion.white_cells`): its time and peak traced memory against the targets
(60 s, 300 MB). Then on the bundled ``layers3`` sample (48 x 48, all pixels, 8 replicates, simulated
at n 1.3): the white Monte Carlo databases are made first (their time printed, then cached, as in
use: a search's records, and the final fits' cells of ``final_photons``); then, timed, a
known-structure fit (boundaries 2, 5 and the scene's scattering per layer, n as the dataset states;
target <= 10 s) and a full search (1 to 4 layers by BIC, boundaries, the scattering, common or with
a base of its own, and the refractive index from 1, 1.33, 1.4, 1.5; target <= 120 s, timed the
second time, once its databases are cached). Each result's layers print their xy error, region
width and the width the data allow. ``tools/evaluate_inversion.py`` and ``tools/evaluate_index.py``
have the accuracy on other scenes. Each time comes with the process's CPU seconds (every thread's):
where other work shares the machine the wall time stretches and the CPU time says what the work cost.

    python benchmarks/bench_inversion.py [--parts cells known search]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np
from ringlight.core.colour.chroma import chromaticity
from ringlight.core.colour.layer_report import truth_layers
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.inversion.forward import Structure
from ringlight.core.inversion.layers import invert
from ringlight.core.inversion.measured import measured_profile
from ringlight.core.inversion.report import profile_radii
from ringlight.core.inversion.search import database_optics
from ringlight.core.inversion.settings import MUS_GRID, N_GRID, SEARCH_BINS, InversionSettings
from ringlight.core.inversion.white_cells import cell_database, run_cells
from ringlight.core.inversion.white_mc import run_white, white_database
from ringlight.core.simulate.samples import sample_dataset

KNOWN_TARGET_S = 10.0
SEARCH_TARGET_S = 120.0
CELLS_PHOTONS = 2_000_000
CELLS_TARGET_S = 60.0
CELLS_TARGET_MB = 300.0
PARTS = ("cells", "known", "search")


def timed(measured, settings):
    """``(inversion, wall seconds, CPU seconds of the process)``: the CPU time, every thread's, says
    what the fit cost where other work shares the machine and stretches the wall time."""
    start, cpu = time.perf_counter(), time.process_time()
    inversion = invert(measured, settings)
    return inversion, time.perf_counter() - start, time.process_time() - cpu


def report(label, inversion, seconds, cpu, target, truth_xy):
    layers = "; ".join(
        f"{index + 1}: error {np.hypot(*(layer.xy - truth_xy[index])):.4f}, width {layer.region_width:.3f}, "
        f"data allow {layer.allowed_width:.3f}{'' if layer.determined else ' (not determined)'}"
        if index < len(truth_xy) else f"{index + 1}: no truth layer"
        for index, layer in enumerate(inversion.layers))
    print(f"{label}: {seconds:.1f} s (target {target:g} s, ratio {seconds / target:.2f}; {cpu:.1f} s of CPU); "
          f"{inversion.notes}; "
          f"chi2/dof {inversion.chi2_per_dof:.2f}; {layers}", flush=True)


def cells_run(known: InversionSettings) -> None:
    """Time and peak traced memory of a CELLS_PHOTONS white run tallied in cells."""
    optics = database_optics(known, known.mus)
    run_white(optics, 64)  # compile
    tracemalloc.start()
    start, cpu = time.perf_counter(), time.process_time()
    cells = run_cells(optics, Structure((0, *known.boundaries)), CELLS_PHOTONS, seed=1)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    held = sum(array.nbytes for array in (cells.cell_class, cells.weight, cells.mean, cells.spread,
                                          cells.batch_weight)) / 1e6
    print(f"white run of {cells.photons} photons in cells (three layers): {seconds:.1f} s (target {CELLS_TARGET_S:g} s, "
          f"ratio {seconds / CELLS_TARGET_S:.2f}; {cpu:.1f} s of CPU); peak traced memory {peak:.0f} MB (target {CELLS_TARGET_MB:g} MB, "
          f"ratio {peak / CELLS_TARGET_MB:.2f}); {len(cells.weight)} cells holding {held:.0f} MB", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS),
                        help="what to time (default: all; the known-structure fit always runs; the search takes longest)")
    parts = parser.parse_args().parts
    dataset = open_dataset(sample_dataset("layers3"))
    measured = measured_profile(dataset, np.ones(dataset.grid_shape, bool), profile_radii(dataset))
    truth_xy = chromaticity(truth_layers(dataset)[1], dataset.colorspace)
    known = InversionSettings(3, (2, 5), (0.5, 0.5, 1.5), 1.3, 0.0, 24.0)
    search = InversionSettings(None, None, None, None, 0.0, 24.0)
    if "cells" in parts:
        cells_run(known)
    start = time.perf_counter()
    cell_database(database_optics(known, known.mus), Structure((0, *known.boundaries)), known.final_photons)
    print(f"the known structure's white run of {known.final_photons} photons in cells: "
          f"{time.perf_counter() - start:.1f} s (once; cached in the user cache)", flush=True)
    start = time.perf_counter()
    for n in N_GRID:
        for mus in MUS_GRID:
            white_database(database_optics(search, mus, n), search.photons)
    print(f"white databases: {len(MUS_GRID) * len(N_GRID)} of {search.photons} photons ({SEARCH_BINS} depth "
          f"bins for the search), {time.perf_counter() - start:.1f} s (once; cached in the user cache)", flush=True)
    report("layers3, known structure and index", *timed(measured, known), KNOWN_TARGET_S, truth_xy)
    if "search" not in parts:
        return
    # A search also makes the databases of a base that scatters otherwise, and the cells of the
    # structures it fits at the end (cached as it goes): the first search pays for them once, the
    # second is timed as in use.
    _, seconds, _ = timed(measured, search)
    print(f"first full search, making its base databases: {seconds:.1f} s", flush=True)
    report("layers3, full search (1-4 layers, boundaries, scattering common or the base's own, index)",
           *timed(measured, search), SEARCH_TARGET_S, truth_xy)


if __name__ == "__main__":
    main()
