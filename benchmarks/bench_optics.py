"""Benchmark of the optical-property maps (not a test: prints figures from one run).

A synthetic SIZE x SIZE homogeneous dataset in memory (the maps' own model response of mus' 0.2,
mua 0.01 per grid step, 3 % noise on every response value, max_radius MAX_RADIUS) is mapped as
``optical_maps`` does it, phase by phase, each timed in this run (wall clock and process CPU time):
  - the ring stack E_r at radii 0 .. max_radius - 1/2 alone (``ring_stack``: what the map is
    computed from, the yardstick);
  - the map's pass (:func:`ringlight.core.optics.one_pass.fit_in_one_pass`, what ``optical_maps``
    runs): 64 pixels of a row at a time, their rings and standard errors (the members' spread),
    then their fits (Gauss-Newton steps from a fine table's nodes, :mod:`ringlight.core.optics.node_fit`,
    the chunk's pixels as the lanes of vectorised loops, :mod:`ringlight.core.optics.chunk_fit`);
  - for comparison, the same in two passes as the maps took it before: the stack and its standard
    errors over the whole grid (``ring_stack_and_errors``), then the per-pixel fits of every pixel
    and channel (``fit_profiles`` on the cached table, each fit making its rings' standard
    deviations from their errors) by the node steps and by the full Levenberg-Marquardt fit on the
    table's splines (the region fits'); and the spread in a pass of its own (``stack_noise``);
  - the fine table's nodes made from the table (once per table, as the table is: reported apart);
in REPEATS rounds within this one process, each round taking every phase once, the order
reversed every other round (a shared machine's load drifts; phases timed minutes apart in separate
runs gave 3.00 x and 4.27 x). Each round gives its own ratios: the map's cost beyond the stack
(the map's pass less the stack) over the stack's, and the whole map's from the dataset over the
stack's (also with the fine nodes made, and by the two passes before); the median over the rounds
is printed with the lowest and highest, and then the map's cost beyond the stack from each phase's
fastest round (the least disturbed: other work only adds time, and the stack, which streams the
responses, varies most). The table's white run is made (or read from the user
cache) before the clock starts: once per n and g. The maps' conversion of the fits to mu_a and
mu_s' and their standard errors (:func:`ringlight.core.optics.maps.maps_from_fit`, numpy over the
whole grid) is timed on its own line, outside the ratios (as before).
Target (issue 38): the map costs at most the time of the stack it is computed from.

    python benchmarks/bench_optics.py [--size 800] [--max-radius 8] [--photons 1000000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ringlight.core.optics.pixel_fit import fit_profiles
from ringlight.core.optics import node_fit
from ringlight.core.optics.one_pass import fit_in_one_pass
from ringlight.core.optics.maps import MODEL_FLOOR, error_freedom, maps_from_fit, profile_radii, ring_errors, t_inflation
from ringlight.core.optics.radial import radial_run
from ringlight.core.optics.synthetic import homogeneous_dataset
from ringlight.core.optics.table import table_for
from ringlight.core.rings.stack_spread import ring_stack_and_errors
from ringlight.core.rings.stacks import ring_stack


def model_kernel(table, half: int, musp: float, mua: float) -> np.ndarray:
    """(2 half + 1, 2 half + 1, 3): each offset given its ring's model value (a radial response)."""
    from ringlight.core.rings.geometry import ring_geometry

    profile = table.profile(musp, mua)
    kernel = np.zeros((2 * half + 1, 2 * half + 1, 3))
    for radius, value in zip(table.radii, profile):
        for dy, dx in ring_geometry(float(radius)).offsets:
            kernel[half + dy, half + dx] = value
    return kernel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=800)
    parser.add_argument("--max-radius", type=float, default=8.0)
    parser.add_argument("--photons", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=5, help="rounds (each times every phase once)")
    args = parser.parse_args()
    run = radial_run(1.4, 0.0, args.photons)  # cached: the table is made once per n and g
    radii = np.arange(0.0, np.floor(args.max_radius - 0.5) + 1.0)
    table = table_for(1.4, 0.0, radii, photons=args.photons)
    kernel = model_kernel(table, int(np.ceil(args.max_radius)), 0.2, 0.01)
    start = time.perf_counter()
    dataset = homogeneous_dataset(kernel, args.size, args.size, max_radius=args.max_radius,
                                  member_noise=np.full(len(radii) + 1, 0.03), n=1.4, g=0.0)
    print(f"{args.size} x {args.size} grid, max_radius {args.max_radius:g}: responses "
          f"{dataset.responses.nbytes / 2**30:.2f} GiB, made in {time.perf_counter() - start:.1f} s; "
          f"white run of {run.photons} photons took {run.seconds:.1f} s when it was made")
    assert np.array_equal(radii, profile_radii(dataset))
    small = homogeneous_dataset(kernel, 24, 24, max_radius=args.max_radius, n=1.4, g=0.0)
    # Compiled kernels loaded before the clock.
    ring_stack(small, radii), ring_errors(small, radii)
    stack, errors = ring_stack_and_errors(small, radii)
    inflation = t_inflation(error_freedom(dataset, radii, "ring spread"))
    for estimator in ("nodes", "full"):
        fit_profiles(table, stack.images, errors, np.ones(3), counts=stack.counts, floor=MODEL_FLOOR,
                     inflation=inflation, estimator=estimator)
    fit_in_one_pass(small, radii, table, np.ones(3), MODEL_FLOOR, inflation)

    stack, errors = ring_stack_and_errors(dataset, radii)  # the fits' input, the same every round
    fitted, complete = fit_in_one_pass(dataset, radii, table, np.ones(3), MODEL_FLOOR, inflation)  # the conversion's

    def fits(estimator):
        return lambda: fit_profiles(table, stack.images, errors, np.ones(3), counts=stack.counts, floor=MODEL_FLOOR,
                                    inflation=inflation, estimator=estimator)

    def fine_nodes():
        node_fit._FINE.pop(table, None)  # made again: what a new table costs
        return node_fit.fine_nodes(table)

    phases = {"stack": lambda: ring_stack(dataset, radii),
              "map pass": lambda: fit_in_one_pass(dataset, radii, table, np.ones(3), MODEL_FLOOR, inflation)[0],
              "one pass": lambda: ring_stack_and_errors(dataset, radii),
              "separate spread": lambda: ring_errors(dataset, radii), "fits": fits("nodes"), "full fits": fits("full"),
              "fine nodes": fine_nodes,
              "conversion": lambda: maps_from_fit(fitted, table, None, complete, radii, "ring spread", np.ones(3))}
    times = {name: [] for name in phases}  # per phase, per round: (wall, CPU) seconds
    results = {}
    for round_ in range(max(1, args.repeats)):
        order = list(phases) if round_ % 2 == 0 else list(phases)[::-1]
        for name in order:
            wall, cpu = time.perf_counter(), time.process_time()
            results[name] = phases[name]()
            times[name].append((time.perf_counter() - wall, time.process_time() - cpu))
    times = {name: np.asarray(value) for name, value in times.items()}  # (rounds, 2)
    count = args.size * args.size * 3

    def outcome(fitted):
        converged = float(np.mean(fitted["status"] == 0))
        musp = (1.0 - table.g) * np.exp(fitted["u"])
        shares = np.bincount(fitted["node_steps"].ravel(), minlength=3) / fitted["node_steps"].size
        steps = (f"; full fits {shares[0]:.1%}, from one node {shares[1]:.1%}, two {shares[2]:.1%}"
                 if shares[0] < 1 else "")
        return f"{converged:.1%} converged, median mus' {np.nanmedian(musp):.4f} for 0.2{steps}"

    def spread(values):
        return f"{np.median(values):5.2f} ({np.min(values):.2f}-{np.max(values):.2f})"

    def line(label, name, extra=""):
        seconds, ratio = times[name], times[name] / times["stack"]
        print(f"{label:44s} {spread(seconds[:, 0])} s wall, {spread(ratio[:, 0])} x; "
              f"{spread(seconds[:, 1])} s CPU, {spread(ratio[:, 1])} x{extra}")

    print(f"{'phase':44s} median (lowest-highest) of {len(times['stack'])} rounds, and over the same round's stack")
    line(f"ring stack ({len(radii)} radii)", "stack")
    line("the map's pass: stack, errors, fits together", "map pass", f"  ({outcome(results['map pass'])})")
    line("stack + errors in one pass (before)", "one pass")
    line("errors in a pass of their own", "separate spread", "  (before; not in the map)")
    for name, label in (("fits", "fits, node steps"), ("full fits", "fits, full (before)")):
        line(f"{label} ({count} pixel channels)", name, f"  ({np.median(times[name][:, 1]) / count * 1e6:.2f} us CPU "
             f"each, {outcome(results[name])})")
    line("fine nodes (once per table)", "fine nodes")
    line("the fits to mu_a, mu_s' maps (not in the map's)", "conversion")
    for index, unit in ((0, "wall"), (1, "CPU")):
        separate = times["one pass"][:, index] + times["fits"][:, index]
        for label, whole in (("", times["map pass"][:, index]),
                             (", fine nodes made", times["map pass"][:, index] + times["fine nodes"][:, index]),
                             (", stack + errors, then fits (before)", separate),
                             (", then full fits (before)", times["one pass"][:, index] + times["full fits"][:, index])):
            own = whole - times["stack"][:, index]
            print(f"map ({unit:4s}{label}): from the dataset {spread(whole / times['stack'][:, index])} x the stack; "
                  f"beyond the stack (errors + fits) {spread(own / times['stack'][:, index])} x (target <= 1)")
        # Other work on the machine only adds time: the fastest round of each phase is its least
        # disturbed, and the stack (streaming the responses) is disturbed most.
        fastest = times["stack"][:, index].min()
        print(f"map ({unit:4s}, each phase's fastest round): beyond the stack "
              f"{(times['map pass'][:, index].min() - fastest) / fastest:.2f} x (target <= 1)")


if __name__ == "__main__":
    main()
