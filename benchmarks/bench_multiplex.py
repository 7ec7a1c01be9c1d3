"""Benchmark of Hadamard multiplexing against plain lattice capture (not a test: prints figures).

The simulated rig over the ``red-bead`` preset, seen one camera pixel per grid point, with its
sensor's read noise (2 e-, plus 1/12 of rounding) and Poisson shot noise, no saturation. For each
exposure, the same block-coded lattice frames are captured twice with equal frame count and
exposure: plainly (one lattice frame per capture) and through the S-matrix code (each capture
lights (n + 1) / 2 lattice frames; demultiplexed). The error of each recovered frame against the
noise-free truth (the scene's radiance x sensor gain x exposure) gives, per radius r from the lit
point (grid steps, rounded), SNR(r) = rms(truth) / rms(error); printed is the gain
SNR_multiplexed / SNR_plain per radius, the read-noise limit (n + 1) / (2 sqrt n), and per radius
the crossover: the exposure (and the lit point's own signal in electrons) above which shot noise
makes multiplexing lose (gain < 1).

    python benchmarks/bench_multiplex.py [--order 15] [--max-radius 4] [--size 24] [--trials 2]
"""

from __future__ import annotations

import argparse
import zlib

import numpy as np
from ringlight.core.capture.multiplex import coded_lit, demultiplex
from ringlight.core.capture.scan_plan import ScanPlan
from ringlight.core.capture.simulated_presets import preset_rig
from ringlight.core.capture.simulated_rig import CameraSampling, SensorModel, SimulatedRig


def cached_radiance(rig: SimulatedRig) -> None:
    """Memoise the rig's noise-free scene radiance per pattern (the camera's noise is unchanged)."""
    compute, memo = rig.scene_radiance, {}

    def radiance(pattern):
        key = zlib.crc32(pattern.tobytes())
        if key not in memo:
            memo[key] = compute(pattern)
        return memo[key]
    rig.scene_radiance = radiance


def errors_by_radius(rig: SimulatedRig, plan: ScanPlan, exposure: float, multiplexed: bool, max_radius: float):
    """(squared error sums, squared truth sums, counts) per integer radius over the coded blocks."""
    frames = plan.frames()
    radii = int(np.ceil(max_radius)) + 1
    error2, truth2, counts = np.zeros(radii), np.zeros(radii), np.zeros(radii)
    rows, cols = np.mgrid[:rig.size[0], :rig.size[1]]
    for indices, code in plan.blocks():
        if code is None:
            continue
        lit_sets = coded_lit(frames, indices, code if multiplexed else None)
        captures = []
        for lit in lit_sets:
            rig.projector.show(plan.pattern(lit, rig.size))
            captures.append(rig.camera.capture(exposure) - rig.sensor.black_level)
        recovered = demultiplex(np.stack(captures), code if multiplexed else None)
        for index, frame in zip(indices, recovered):
            lit = frames[index]
            truth = rig.scene_radiance(plan.pattern(lit, rig.size)) * rig.sensor.gain * exposure
            distance = np.min(np.hypot(rows[..., None] - lit[:, 0], cols[..., None] - lit[:, 1]), axis=-1)
            radius = np.round(distance).astype(int)
            inside = distance <= max_radius
            for channel in range(3):
                np.add.at(error2, radius[inside], (frame[..., channel] - truth[..., channel])[inside] ** 2)
                np.add.at(truth2, radius[inside], truth[..., channel][inside] ** 2)
                np.add.at(counts, radius[inside], 1)
    return error2, truth2, counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--order", type=int, default=15, help="S-matrix order 2^k - 1 (default 15)")
    parser.add_argument("--max-radius", type=float, default=4.0)
    parser.add_argument("--size", type=int, default=24)
    parser.add_argument("--trials", type=int, default=2)
    args = parser.parse_args()

    windows = preset_rig(size=f"{args.size}x{args.size}", photons="600").windows
    centre, keep = (windows.shape[2] - 1) // 2, int(np.ceil(args.max_radius))
    windows = windows[:, :, centre - keep:centre + keep + 1, centre - keep:centre + keep + 1]
    sensor = SensorModel(bits=40, exposure_range=(1e-9, 100.0))  # no saturation: equal exposures compare
    plan = ScanPlan((0, 0, args.size, args.size), args.max_radius, (1.0,), multiplex=args.order)
    peak = float(windows[:, :, keep, keep].mean()) * sensor.gain  # a lit point's own electrons per second
    exposures = np.geomspace(1e-7, 1e-2, 11)
    n = args.order
    print(f"S-matrix order {n}: {sum(len(i) for i, c in plan.blocks() if c is not None)} coded lattice frames "
          f"of {len(plan.frames())}, read noise {sensor.read_noise} e-, {args.trials} trials; "
          f"read-noise limit of the gain (n+1)/(2 sqrt n) = {(n + 1) / (2 * np.sqrt(n)):.2f}")
    radii = np.arange(int(np.ceil(args.max_radius)) + 1)
    print(f"{'exposure s':>11} {'lit e-':>9}  " + " ".join(f"{'r=' + str(r):>6}" for r in radii))
    gains = []
    for exposure in exposures:
        totals = {}
        for multiplexed in (False, True):
            sums = np.zeros((3, len(radii)))
            for trial in range(args.trials):
                rig = SimulatedRig(windows, CameraSampling(1.0, 0.0, (0.0, 0.0), 0), sensor, seed=trial)
                cached_radiance(rig)
                sums += np.array(errors_by_radius(rig, plan, exposure, multiplexed, args.max_radius))
            totals[multiplexed] = np.sqrt(sums[1] / sums[0])  # SNR per radius
        gain = totals[True] / totals[False]
        gains.append(gain)
        print(f"{exposure:11.2e} {peak * exposure:9.3g}  " + " ".join(f"{g:6.2f}" for g in gain))
    gains = np.array(gains)
    print("crossover (multiplexing loses above):")
    for r in radii:
        below = np.flatnonzero(gains[:, r] < 1)
        if len(below) == 0:
            print(f"  r = {r}: none up to {exposures[-1]:.1e} s")
            continue
        k = below[0]
        if k == 0:
            print(f"  r = {r}: already at {exposures[0]:.1e} s")
            continue
        # Interpolate log(exposure) where the gain crosses 1.
        g0, g1 = gains[k - 1, r], gains[k, r]
        t = np.exp(np.log(exposures[k - 1]) + (g0 - 1) / (g0 - g1) * np.log(exposures[k] / exposures[k - 1]))
        print(f"  r = {r}: {t:.2e} s, the lit point's own signal {peak * t:.3g} e-")


if __name__ == "__main__":
    main()
