"""Regenerate the bundled samples (resources/samples/*.npz) with ringlight's own simulator.

Each sample is simulated progressively (:func:`ringlight.core.simulate.progressive.simulate_until`,
the reference estimator) at SIZE x SIZE until the estimated relative noise of T_r at the largest
radius is at most --noise, or --time per sample has passed; it prints the noise per radius (the
figure issue 12 asks for) and the time, and writes the sample file. The run's checkpoint stays in
the user cache: running again with a longer --time continues from it.

    python tools/make_samples.py [--noise 0.05] [--time 10m] [--size 48] [NAME ...]

A layered sample (every lit point sharing one response) can instead be simulated in independent
replicates of a fixed number of photons (:mod:`ringlight.core.simulate.replicates`), which its
dataset then holds, so that its noise (shared by every lit point) is measured:

    python tools/make_samples.py --replicates 8 --photons 128 layers3 skin1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ringlight.app.cli.simulate import parse_duration
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.progressive import noise_radius, simulate_until
from ringlight.core.simulate.replicates import replicate_transient_noise, simulate_replicates
from ringlight.core.simulate.samples import SAMPLES, save_sample

OUT = Path(__file__).resolve().parent.parent / "resources" / "samples"
BATCH = 16


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("names", nargs="*", default=list(SAMPLES))
    parser.add_argument("--noise", type=float, default=0.05)
    parser.add_argument("--time", default="10m")
    parser.add_argument("--size", type=int, default=48)
    parser.add_argument("--replicates", type=int, default=None, help="independent replicates (with --photons)")
    parser.add_argument("--photons", type=int, default=128, help="photons per point of all replicates together")
    args = parser.parse_args()
    for name in args.names:
        scene = load_scene(name, size=(args.size, args.size))
        print(f"{name} at {args.size} x {args.size}, max_radius {scene.max_radius:g}", flush=True)
        if args.replicates:
            transport = simulate_replicates(scene, args.photons, args.replicates)
            noise = replicate_transient_noise(transport, noise_radius(scene))
            print("  noise per radius " + " ".join(f"{r}:{v:.3f}" for r, v in enumerate(noise)), flush=True)
            save_sample(transport, OUT / f"{name}.npz", noise)
            print(f"  wrote {OUT / (name + '.npz')}, {args.replicates} replicates, {transport.seconds:.0f} s of "
                  "simulation", flush=True)
            continue
        transport, status = simulate_until(
            scene, args.noise, parse_duration(args.time), batch=BATCH,
            report=lambda s: print(f"  {s.photons} photons per point: worst noise of T_r, r <= {s.radius}: "
                                   f"{s.worst:.3f}, {s.seconds:.0f} s", flush=True))
        print("  noise per radius " + " ".join(f"{r}:{v:.3f}" for r, v in enumerate(status.noise)), flush=True)
        save_sample(transport, OUT / f"{name}.npz", status.noise)
        print(f"  wrote {OUT / (name + '.npz')} ({(OUT / (name + '.npz')).stat().st_size / 1e6:.1f} MB), "
              f"{status.seconds:.0f} s of simulation", flush=True)
    sys.exit(0)


if __name__ == "__main__":
    main()
