"""Benchmark of the maps' node fits on one cache-resident chunk (not a test: prints figures from one run).

``benchmarks/bench_optics.py`` times a whole 800 x 800 map against its stack; on a shared machine its
ratio moves by a third between rounds (the stack streams 1.41 GiB), far more than a change to the fits
does. This times what the maps' one pass does after each chunk's rings (:mod:`ringlight.core.optics.one_pass`):
:func:`~ringlight.core.optics.node_fit.node_fit_row` over CHUNK pixels and 3 channels whose profiles and
standard errors stay in the core's cache (the benchmark's homogeneous medium, mus' 0.2, mua 0.01 per grid
step, 3 % noise on each response, max_radius 8), called REPEATS times in a compiled loop per trial, one
thread. A trial interrupted by other work only takes longer, so the minimum over TRIALS trials is printed
(with the median), in ns a pixel channel: the rings' weights (the prep) and the Gauss-Newton steps together.

    NUMBA_NUM_THREADS=1 python benchmarks/bench_node_fit.py [--trials 40] [--repeats 200]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from bench_optics import model_kernel

from ringlight.core.optics.maps import MODEL_FLOOR, error_freedom, t_inflation
from ringlight.core.optics.node_fit import fine_nodes, node_fit_row
from ringlight.core.optics.one_pass import CHUNK
from ringlight.core.optics.pixel_fit import coarse_nodes, fit_outputs
from ringlight.core.optics.synthetic import homogeneous_dataset
from ringlight.core.optics.table import table_for
from ringlight.core.rings.stack_spread import ring_stack_and_errors


@numba.njit
def fit_chunk_repeatedly(repeats, start, nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv,
                         images, errors, scale, counts, floor, inflation, out):
    """``node_fit_row`` of the chunk ``repeats`` times, each from the same ``start`` (C, 2)."""
    u, v, cuu, cuv, cvv, chi2, rings, status, steps = out
    for _ in range(repeats):
        node_fit_row(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, images, errors,
                     scale, True, counts, floor, inflation, 0, 0, 0, start.copy(), u, v, cuu, cuv, cvv, chi2, rings,
                     status, steps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=200, help="chunk fits per trial")
    args = parser.parse_args()
    radii = np.arange(0.0, 8.0)
    table = table_for(1.4, 0.0, radii, photons=1_000_000)  # cached: made once per n and g
    dataset = homogeneous_dataset(model_kernel(table, 8, 0.2, 0.01), 20, CHUNK + 20, max_radius=8.0,
                                  member_noise=np.full(len(radii) + 1, 0.03), n=1.4, g=0.0)
    inflation = np.asarray(t_inflation(error_freedom(dataset, radii, "ring spread")), np.float64)
    stack, errors = ring_stack_and_errors(dataset, radii)
    inside = (slice(None), slice(10, 11), slice(10, 10 + CHUNK))  # a row of whole rings
    images, errors = (np.ascontiguousarray(array[inside], np.float32) for array in (stack.images, errors))
    counts = np.ascontiguousarray(stack.counts[inside], np.int32)
    out = fit_outputs(1, CHUNK, 3)
    arguments = (*fine_nodes(table), table.log_profile, coarse_nodes(table.log_profile), table.u0, table.du, table.v0,
                 table.dv, images, errors, np.ones(3), counts, float(MODEL_FLOOR), inflation,
                 tuple(out[name] for name in ("u", "v", "cuu", "cuv", "cvv", "chi2", "rings", "status", "node_steps")))
    # Each channel starts where a fit of the chunk's first pixel ends, as a row's fits do after its first.
    fit_chunk_repeatedly(1, np.full((3, 2), np.nan), *arguments)
    start = np.stack([out["u"][0, 0], out["v"][0, 0]], axis=1)
    fit_chunk_repeatedly(1, start, *arguments)
    steps = np.bincount(out["node_steps"].ravel(), minlength=3)
    seconds = []
    for _ in range(args.trials):
        begin = time.perf_counter()
        fit_chunk_repeatedly(args.repeats, start, *arguments)
        seconds.append(time.perf_counter() - begin)
    each = np.asarray(seconds) / (args.repeats * CHUNK * 3) * 1e9
    print(f"node fits of a {CHUNK}-pixel chunk, 3 channels ({steps[1]} from one node, {steps[2]} from two, "
          f"{steps[0]} full fits): min {each.min():.1f} ns a pixel channel, median {np.median(each):.1f} "
          f"({args.trials} trials of {args.repeats} chunks, numba threads {numba.get_num_threads()})")


if __name__ == "__main__":
    main()
