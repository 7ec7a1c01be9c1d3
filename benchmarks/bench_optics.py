"""Benchmark of the optical-property maps (not a test: prints figures from one run).

A synthetic SIZE x SIZE homogeneous dataset in memory (the maps' own model response of mus' 0.2,
mua 0.01 per grid step, 3 % noise on every response value, max_radius MAX_RADIUS) is mapped as
``optical_maps`` does it, phase by phase, each timed in this run:
  - the ring stack E_r at radii 0 .. max_radius - 1/2 (``ring_stack``, what the map is computed from);
  - the standard errors of those rings (the members' spread, ``stack_noise``);
  - the per-pixel fits of every pixel and channel (``fit_profiles`` on the cached table);
each the best of REPEATS rounds that take them in turn;
then the map's own cost (errors + fits) over the stack's. The table's white run is made (or read
from the user cache) before the clock starts: once per n and g.
Target (issue 38): the map costs at most the time of the stack it is computed from.

    python benchmarks/bench_optics.py [--size 800] [--max-radius 8] [--photons 1000000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ringlight.core.optics.pixel_fit import fit_profiles
from ringlight.core.optics.maps import error_freedom, profile_radii, ring_errors, ring_sigma, t_inflation
from ringlight.core.optics.radial import radial_run
from ringlight.core.optics.synthetic import homogeneous_dataset
from ringlight.core.optics.table import table_for
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
    parser.add_argument("--repeats", type=int, default=3)
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
    ring_stack(small, radii)  # compiled kernels loaded before the clock
    errors, source = ring_errors(small, radii)
    fit_profiles(table, ring_stack(small, radii).images, ring_sigma(ring_stack(small, radii).images, errors,
                                                                  ring_stack(small, radii).counts), np.ones(3))

    stack_seconds = noise_seconds = fit_seconds = np.inf
    for _ in range(args.repeats):  # each phase's best of the rounds, taken in turn (a busy machine)
        start = time.perf_counter()
        stack = ring_stack(dataset, radii)
        stack_seconds = min(stack_seconds, time.perf_counter() - start)
        start = time.perf_counter()
        errors, source = ring_errors(dataset, radii)
        errors = errors * t_inflation(error_freedom(dataset, radii, source))[:, None, None, None]
        sigma = ring_sigma(stack.images, errors, stack.counts)
        noise_seconds = min(noise_seconds, time.perf_counter() - start)
        start = time.perf_counter()
        fitted = fit_profiles(table, stack.images, sigma, np.ones(3))
        fit_seconds = min(fit_seconds, time.perf_counter() - start)
    fits = args.size * args.size * 3
    converged = float(np.mean(fitted["status"] == 0))
    musp = (1.0 - table.g) * np.exp(fitted["u"])
    print(f"ring stack ({len(radii)} radii):       {stack_seconds:7.2f} s")
    print(f"ring errors ({source}):     {noise_seconds:7.2f} s  ({noise_seconds / stack_seconds:.2f} x the stack)")
    print(f"fits ({fits} pixel channels): {fit_seconds:7.2f} s  ({fit_seconds / stack_seconds:.2f} x the stack, "
          f"{fit_seconds / fits * 1e6:.2f} us each, {converged:.1%} converged, median mus' {np.nanmedian(musp):.4f} "
          f"for 0.2)")
    own = noise_seconds + fit_seconds
    print(f"map from the stack (errors + fits): {own:.2f} s = {own / stack_seconds:.2f} x the stack "
          f"(target <= 1); fits alone {fit_seconds / stack_seconds:.2f} x")


if __name__ == "__main__":
    main()
