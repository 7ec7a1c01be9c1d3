"""Benchmark of the maps' one pass on one cache-resident chunk (not a test: prints figures from one run).

``benchmarks/bench_optics.py`` times a whole 800 x 800 map against its stack; on a shared machine its
ratio moves by a third between rounds (the stack streams 1.41 GiB), far more than a change to either
half of the pass does. This times each half of what the maps' one pass does per chunk
(:mod:`ringlight.core.optics.one_pass`) on CHUNK pixels of one grid row whose data stay in the core's
cache (the benchmark's homogeneous medium, mus' 0.2, mua 0.01 per grid step, 3 % noise on each
response, max_radius 8), after the yardstick, the stack's own kernel on the same chunk:
  - the stack's sums (``_ring_sums``, as ``ring_stack`` runs it: its parallel loop's launch included);
  - the chunk's rings and their standard errors from the responses
    (:func:`~ringlight.core.rings.stack_spread.spread_row`);
  - its node fits, 3 channels (:func:`~ringlight.core.optics.chunk_fit.node_fit_chunk`): the rings'
    weights and the Gauss-Newton steps together;
each called REPEATS times in a compiled loop per trial, one thread. A trial interrupted by other work
only takes longer, so the minimum over TRIALS trials is printed (with the median), in ns a pixel
channel.

    NUMBA_NUM_THREADS=1 python benchmarks/bench_chunk.py [--trials 200] [--repeats 40]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from bench_optics import model_kernel

from ringlight.core.optics.maps import MODEL_FLOOR, error_freedom, t_inflation
from ringlight.core.optics.chunk_fit import CHUNK, chunk_scratch, node_fit_chunk
from ringlight.core.optics.node_fit import fine_nodes
from ringlight.core.optics.pixel_fit import coarse_nodes, fit_outputs
from ringlight.core.optics.synthetic import homogeneous_dataset
from ringlight.core.optics.table import table_for
from ringlight.core.rings.members import ring_members
from ringlight.core.rings.stack_spread import band_members, spread_row, spread_rings
from ringlight.core.rings.stacks import _ring_sums

ROW, FIRST = 10, 10
"""The chunk: grid row ROW from column FIRST, every ring whole (max_radius 8 on a 20 x (CHUNK + 20) grid)."""


@numba.njit
def stack_chunk_repeatedly(repeats, responses, first, stop, weight_start, weights, unweighted, counts, totals, images):
    """The stack's own sums (``_ring_sums``, as ``ring_stack`` runs them) of the chunk ``repeats`` times."""
    for _ in range(repeats):
        _ring_sums(responses, first, stop, weight_start, weights, unweighted, counts, totals, images)


@numba.njit
def spread_chunk_repeatedly(repeats, pixels, lit, dy, dx, first, stop, groups, ring_groups, counts, images, errors):
    """``spread_row`` of the chunk ``repeats`` times."""
    for _ in range(repeats):
        spread_row(pixels, ROW, FIRST, lit, dy, dx, first, stop, groups, ring_groups, counts, images, errors)


@numba.njit
def fit_chunk_repeatedly(repeats, start, nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv,
                         lanes, lane_errors, scale, counts, floor, inflation, out):
    """``node_fit_chunk`` of the chunk ``repeats`` times, each from the same ``start`` (C, 2)."""
    u, v, cuu, cuv, cvv, chi2, rings, status, steps = out
    scratch = chunk_scratch(3, lanes.shape[1])
    for _ in range(repeats):
        node_fit_chunk(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, lanes,
                       lane_errors, CHUNK, scale, True, counts, floor, inflation, 0, 0, start.copy(), u, v, cuu, cuv,
                       cvv, chi2, rings, status, steps, scratch)


def fastest(trials: int, repeats: int, call) -> np.ndarray:
    """(trials,) ns a pixel channel of ``call(repeats)``, each trial timed alone."""
    seconds = []
    for _ in range(trials):
        begin = time.perf_counter()
        call(repeats)
        seconds.append(time.perf_counter() - begin)
    return np.asarray(seconds) / (repeats * CHUNK * 3) * 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=40, help="chunks per trial")
    args = parser.parse_args()
    radii = np.arange(0.0, 8.0)
    table = table_for(1.4, 0.0, radii, photons=1_000_000)  # cached: made once per n and g
    dataset = homogeneous_dataset(model_kernel(table, 8, 0.2, 0.01), 2 * ROW, CHUNK + 2 * FIRST, max_radius=8.0,
                                  member_noise=np.full(len(radii) + 1, 0.03), n=1.4, g=0.0)
    inflation = np.asarray(t_inflation(error_freedom(dataset, radii, "ring spread")), np.float64)
    rings = spread_rings(dataset, radii)
    row = np.ascontiguousarray(dataset.rows(ROW, ROW + 1)).reshape(1, dataset.grid_shape[1], -1)
    pixels = row[0, FIRST:FIRST + CHUNK]
    counts = np.ascontiguousarray(band_members(dataset, rings, ROW, ROW + 1)[:, :, FIRST:FIRST + CHUNK])
    # The pass's scratch: the rings channel by channel, (3, R, CHUNK), written through (R, CHUNK, 3) views.
    lanes = np.empty((3, len(radii), CHUNK), np.float32)
    lane_errors = np.empty((3, len(radii), CHUNK), np.float32)
    images = lanes.transpose(1, 2, 0)
    spread = (pixels, *rings.kernel_arguments, counts[:, 0], images, lane_errors.transpose(1, 2, 0))
    spread_chunk_repeatedly(1, *spread)
    out = fit_outputs(1, CHUNK, 3)
    fits = (*fine_nodes(table), table.log_profile, coarse_nodes(table.log_profile), table.u0, table.du, table.v0,
            table.dv, lanes, lane_errors, np.ones(3), counts, float(MODEL_FLOOR), inflation,
            tuple(out[name] for name in ("u", "v", "cuu", "cuv", "cvv", "chi2", "rings", "status", "node_steps")))
    # Each channel starts where a fit of the chunk's first pixel ends, as a row's fits do after its first.
    fit_chunk_repeatedly(1, np.full((3, 2), np.nan), *fits)
    start = np.stack([out["u"][0, 0], out["v"][0, 0]], axis=1)
    fit_chunk_repeatedly(1, start, *fits)
    steps = np.bincount(out["node_steps"].ravel(), minlength=3)
    # The yardstick: the stack alone, its rings' sums over the same chunk.
    chunk = np.ascontiguousarray(pixels).reshape(1, CHUNK, -1, 3)
    members, totals = ring_members(dataset.lit, dataset.observed, dataset.offsets, rings.tables, rings.unweighted,
                                   ROW, ROW + 1)
    window = slice(FIRST, FIRST + CHUNK)
    stack = (chunk, *rings.tables, rings.unweighted, np.ascontiguousarray(members[:, :, window]),
             np.ascontiguousarray(totals[:, :, window]), np.empty((len(radii), 1, CHUNK, 3), np.float32))
    stack_chunk_repeatedly(1, *stack)
    assert np.allclose(stack[-1][:, 0], images, rtol=1e-6, atol=0.0)  # the same rings as the pass's
    halves = {"the stack's sums": lambda repeats: stack_chunk_repeatedly(repeats, *stack),
              "rings and errors": lambda repeats: spread_chunk_repeatedly(repeats, *spread),
              "node fits": lambda repeats: fit_chunk_repeatedly(repeats, start, *fits)}
    print(f"a {CHUNK}-pixel chunk, 3 channels, max_radius 8 ({steps[1]} fits from one node, {steps[2]} from two, "
          f"{steps[0]} full fits); {args.trials} trials of {args.repeats} chunks, "
          f"numba threads {numba.get_num_threads()}")
    for name, call in halves.items():
        each = fastest(args.trials, args.repeats, call)
        print(f"{name:17s} min {each.min():6.1f} ns a pixel channel, median {np.median(each):6.1f}")


if __name__ == "__main__":
    main()
