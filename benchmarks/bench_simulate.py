"""Benchmark of the simulator (not a test): photons per second of both measures, and noise per radius.

(1) Photons per second on one core, after a warm-up compile, for the exitance (analogue exits,
    the quantity of MCML's tables) and the camera measure (next-event estimation toward a camera
    looking straight down, the default):
    (a) MCML manual Table 6.1 slab: n = 1, mu_a = 10/cm, mu_s = 90/cm, g = 0.75, d = 0.02 cm;
    (b) the matched (n = 1) isotropic half-space of albedo 0.9.
    The exitance is printed with its standard error next to the published value as a check that
    the timed work is the real thing. MCML (single-thread C) does 3.6-4.2 M and 0.42-0.60 M
    photons/s on this class of machine.
(2) Relative noise of the ring light images E_r, r = 0..8, of a preset (red-bead at 32 x 32 by
    default) at equal simulation time for both measures: two seeds a and b,
    RMS(E_a - E_b) / sqrt(2) / RMS((E_a + E_b) / 2) over the grid and the three channels.

    python benchmarks/bench_simulate.py [--photons 2000000] [--preset red-bead] [--size 32]
                                        [--seconds 15]
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np
from ringlight.core.rings.geometry import ring_geometry
from ringlight.core.simulate.camera import optics
from ringlight.core.simulate.photon import total_run
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.tables import single_channel_tables
from ringlight.core.simulate.transport import simulate_transport

CASES = {
    "MCML slab (Table 6.1)": dict(mua=10.0, mus=90.0, g=0.75, n=1.0, depth=0.02, reference=0.09739,
                                  mcml=(3.6e6, 4.2e6)),
    "matched isotropic half-space, albedo 0.9": dict(mua=0.1, mus=0.9, g=0.0, n=1.0, depth=math.inf,
                                                     reference=0.41495, mcml=(0.42e6, 0.60e6)),
}
MEASURES = ("exitance", "camera")
RADII = range(9)


def photon_rates(photons: int) -> None:
    """Part (1): single-core photons per second of both measures on the MCML cases."""
    volume = np.zeros((1, 1, 1), np.uint8)
    for name, case in CASES.items():
        mu_t = case["mua"] + case["mus"]
        tables = single_channel_tables([mu_t], [case["mus"] / mu_t], [case["g"]])
        geometry = optics(case["n"], case["depth"], uniform_mu_t=mu_t)
        count = photons if case["g"] else photons // 4
        print(name)
        for measure in MEASURES:
            camera = measure == "camera"
            total_run(volume, *tables, geometry, camera, 1000, 0, 0)
            start = time.perf_counter()
            (total,), (total_sq,) = total_run(volume, *tables, geometry, camera, count, 1, 0)
            seconds = time.perf_counter() - start
            mean = total / count
            error = math.sqrt((total_sq / count - mean * mean) / count)
            rate = count / seconds
            low, high = case["mcml"]
            check = (f"reflectance {mean:.5f} +- {error:.5f} (published {case['reference']})" if not camera
                     else f"normal-in normal-out reflectance factor {mean:.5f} +- {error:.5f}")
            print(f"  {measure:9s} {rate / 1e6:.2f} M photons/s on one core (MCML {low / 1e6:.2f}-{high / 1e6:.2f}); "
                  f"{check}")


def ring_light_images(windows: np.ndarray) -> np.ndarray:
    """(len(RADII), H, W, 3) E_r from (H, W, 2R+1, 2R+1, 3) windows, FORMAT.md's default rings."""
    height, width, size = windows.shape[:3]
    radius = size // 2
    images = np.zeros((len(RADII), height, width, 3))
    for index, r in enumerate(RADII):
        total = np.zeros((height, width, 3))
        count = np.zeros((height, width, 1))
        for dy, dx in ring_geometry(r).offsets:
            # q = p + d lights p, seen at offset -d of q's window.
            ys, xs = slice(max(0, -dy), min(height, height - dy)), slice(max(0, -dx), min(width, width - dx))
            qs = slice(ys.start + dy, ys.stop + dy), slice(xs.start + dx, xs.stop + dx)
            total[ys, xs] += windows[qs[0], qs[1], radius - dy, radius - dx]
            count[ys, xs] += 1
        images[index] = total / np.maximum(count, 1)
    return images


def noise_at_equal_time(preset: str, size: int, seconds: float) -> None:
    """Part (2): E_r noise per radius of both measures, each run given about ``seconds``."""
    scene = load_scene(preset, size=(size, size))
    print(f"\n{preset} at {size} x {size}, two seeds per measure, about {seconds:g} s per run")
    results = {}
    for measure in MEASURES:
        measured = replace(scene, measure=measure)
        pilot = simulate_transport(measured, photons=20, seed=0)  # also the compile
        pilot = simulate_transport(measured, photons=100, seed=0)
        photons = max(1, int(100 * seconds / pilot.seconds))
        runs = [simulate_transport(measured, photons=photons, seed=seed) for seed in (1, 2)]
        a, b = (ring_light_images(run.windows.astype(np.float64)) for run in runs)
        noise = np.array([math.sqrt(np.mean((a[i] - b[i]) ** 2) / 2) / math.sqrt(np.mean(((a[i] + b[i]) / 2) ** 2))
                          for i in range(len(RADII))])
        taken = (runs[0].seconds + runs[1].seconds) / 2
        # Noise falls as 1 / sqrt(time): this puts both measures at exactly ``seconds``.
        results[measure] = noise, noise * math.sqrt(taken / seconds)
        traced = photons * size * size * (1 if scene.grey else 3)
        print(f"  {measure:9s} {photons} photons per point per channel, {runs[0].seconds:.1f} s and "
              f"{runs[1].seconds:.1f} s, {traced / taken / 1e6:.3f} M photons/s (all threads)")
    print("  r" + " " * 24 + " ".join(f"{r:6d}" for r in RADII))
    for measure, (noise, scaled) in results.items():
        print(f"  {measure:9s} as run         " + " ".join(f"{value:6.3f}" for value in noise))
        print(f"  {measure:9s} at {seconds:5.1f} s      " + " ".join(f"{value:6.3f}" for value in scaled))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--photons", type=int, default=2_000_000)
    parser.add_argument("--preset", default="red-bead")
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--seconds", type=float, default=15.0)
    args = parser.parse_args()
    photon_rates(args.photons)
    noise_at_equal_time(args.preset, args.size, args.seconds)


if __name__ == "__main__":
    main()
