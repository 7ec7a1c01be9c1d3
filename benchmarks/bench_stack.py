"""Benchmark of transient stack computation (not a test: prints figures from one run).

A synthetic 96 x 96 grid with max_radius 24 and a 25-radius transient stack spanning the usable
radii. Printed, all measured in this run:
  - stack time and the floor: one pass reading the whole response array on every core (a
    compiled parallel sum: the machine's parallel read bandwidth), each the best of 7 rounds
    that take them in turn, and numpy's single-threaded sum beside them;
  - the standard errors of the same stack (``stack_noise``), timed in the same rounds, against
    the stack;
  - a naive per-pixel Python loop over ring points, timed on a subset of pixels and scaled;
  - peak memory during the stack over the response array's size (tracemalloc).
Targets (core issue): stack <= 2x floor, >= 500x faster than naive, peak <= 2x the array.

    python benchmarks/bench_stack.py [--size 96] [--max-radius 24] [--radii 25] [--repeats 7]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from pathlib import Path

import numba
import numpy as np
from ringlight.core import ImpulseDataset, disc_offsets, ring_geometry, transient_stack
from ringlight.core.dataset.manifest import Manifest
from ringlight.core.rings.noise import stack_noise


def synthetic_dataset(size: int, max_radius: float, seed: int = 0) -> ImpulseDataset:
    """An in-memory dataset with random responses and 2 % missing points (no EXR involved).

    Responses from missing or out-of-grid points are 0, the invariant of the response model."""
    rng = np.random.default_rng(seed)
    offsets = disc_offsets(max_radius)
    responses = rng.random((size, size, len(offsets), 3), dtype=np.float32)
    lit_counts = (rng.random((size, size)) > 0.02).astype(np.int32)
    for k, (dy, dx) in enumerate(offsets.tolist()):
        shifted = np.zeros((size, size), bool)
        shifted[max(-dy, 0):size - max(dy, 0), max(-dx, 0):size - max(dx, 0)] = (
            lit_counts[max(dy, 0):size - max(-dy, 0), max(dx, 0):size - max(-dx, 0)] > 0)
        responses[~shifted, k] = 0.0
    manifest = Manifest(
        folder=Path("synthetic"), height=size, width=size, pitch_mm=None, colorspace="sRGB",
        frame_space="grid", mapping=None, max_radius=max_radius, frames=(), dark=None,
        ground_truth=None, notes=None,
    )
    return ImpulseDataset(manifest, max_radius, offsets, responses, lit_counts, np.ones((size, size), bool))


def naive_transient_pixel(dataset: ImpulseDataset, radii, step, y, x):
    """T_r(p) for one pixel with Python loops over ring points (the reference to beat)."""
    height, width = dataset.grid_shape
    index = {tuple(o): k for k, o in enumerate(dataset.offsets.tolist())}

    def ring_mean(radius):
        total, count = [0.0, 0.0, 0.0], 0
        for dy, dx in ring_geometry(radius).offsets.tolist():
            qy, qx = y + dy, x + dx
            if 0 <= qy < height and 0 <= qx < width and dataset.lit_counts[qy, qx]:
                value = dataset.responses[y, x, index[(dy, dx)]]
                total = [t + float(v) for t, v in zip(total, value)]
                count += 1
        return [t / count for t in total] if count else [float("nan")] * 3

    return [[a - b for a, b in zip(ring_mean(r), ring_mean(r + step))] for r in radii]


@numba.njit(parallel=True, cache=True, fastmath=True)
def parallel_sum(responses):
    """Sum of a (H, W, K, 3) array, rows in parallel and vectorised (reassociated): one read of
    every byte on every core."""
    totals = np.zeros(responses.shape[0])
    for y in numba.prange(responses.shape[0]):
        total = 0.0
        for x in range(responses.shape[1]):
            for k in range(responses.shape[2]):
                for c in range(3):
                    total += responses[y, x, k, c]
        totals[y] = total
    return totals.sum()


def best_of(repeats, function):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def interleaved_best(repeats, *functions):
    """Best time of each function over ``repeats`` rounds that call them in turn, so that the
    speed of a shared machine (on these VMs the same pass takes up to 1.6x longer for seconds at a
    time) weighs on each alike."""
    times = [[] for _ in functions]
    for _ in range(repeats):
        for function, taken in zip(functions, times):
            start = time.perf_counter()
            function()
            taken.append(time.perf_counter() - start)
    return [min(taken) for taken in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--max-radius", type=float, default=24.0)
    parser.add_argument("--radii", type=int, default=25)
    parser.add_argument("--naive-pixels", type=int, default=24)
    parser.add_argument("--repeats", type=int, default=7, help="rounds of stack and floor, taken in turn")
    args = parser.parse_args()

    dataset = synthetic_dataset(args.size, args.max_radius)
    # 25 radii from 0 whose outer rings (r + dr + w/2) stay within max_radius.
    last = args.max_radius - 1.5
    radii = np.linspace(0.0, last, args.radii)
    step = float(radii[1] - radii[0])
    transient_stack(synthetic_dataset(8, 4), [0, 1])  # compile outside the timing

    array_bytes = dataset.responses.nbytes
    parallel_sum(dataset.responses)  # compile outside the timing
    stack_noise(dataset, radii[:2], step)  # compile outside the timing
    stack_time, floor_time, noise_time = interleaved_best(
        args.repeats, lambda: transient_stack(dataset, radii, step), lambda: parallel_sum(dataset.responses),
        lambda: stack_noise(dataset, radii, step))
    numpy_time = best_of(3, lambda: dataset.responses.sum())

    rng = np.random.default_rng(1)
    pixels = rng.integers(0, args.size, (args.naive_pixels, 2))
    start = time.perf_counter()
    naive = [naive_transient_pixel(dataset, radii, step, int(y), int(x)) for y, x in pixels]
    naive_time = (time.perf_counter() - start) * args.size * args.size / len(pixels)
    stack = transient_stack(dataset, radii, step)
    for (y, x), values in zip(pixels, naive):
        np.testing.assert_allclose(stack.images[:, y, x], np.array(values), rtol=1e-4, atol=1e-6)

    tracemalloc.start()
    transient_stack(dataset, radii, step)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    print(f"grid {args.size} x {args.size}, max_radius {args.max_radius:g}, "
          f"{len(dataset.offsets)} offsets, responses {array_bytes / 2**20:.0f} MiB")
    print(f"transient stack: {len(radii)} radii {radii[0]:g}..{radii[-1]:g} step {step:.4g}")
    print(f"stack time            {stack_time * 1e3:9.1f} ms")
    print(f"floor (parallel read) {floor_time * 1e3:9.1f} ms   ({array_bytes / floor_time / 2**30:.1f} GiB/s; "
          f"numpy's sum {numpy_time * 1e3:.1f} ms)")
    print(f"stack / floor         {stack_time / floor_time:9.2f}   (target <= 2)")
    print(f"noise of the stack    {noise_time * 1e3:9.1f} ms   ({noise_time / stack_time:.2f}x the stack; "
          "the noise issue: about the stack's cost)")
    print(f"naive loop (scaled)   {naive_time:9.1f} s    from {len(pixels)} pixels, values checked")
    print(f"naive / stack         {naive_time / stack_time:9.0f}   (target >= 500)")
    print(f"peak memory / array   {(array_bytes + peak) / array_bytes:9.3f}   "
          f"(array + {peak / 2**20:.1f} MiB traced during the stack; target <= 2)")


if __name__ == "__main__":
    main()
