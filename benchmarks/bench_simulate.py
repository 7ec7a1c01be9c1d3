"""Benchmark of the photon loop (not a test): photons per second per core, next to MCML.

(a) MCML manual Table 6.1 slab: n = 1, mu_a = 10/cm, mu_s = 90/cm, g = 0.75, d = 0.02 cm;
(b) the matched (n = 1) isotropic half-space of albedo 0.9.
Each runs single-threaded (one core) after a warm-up compile; the reflectance is printed with
its standard error as a check that the timed work is the real thing. MCML (single-thread C) does
3.6-4.2 M and 0.42-0.60 M photons/s on this class of machine (core issue of the simulator).

    python benchmarks/bench_simulate.py [--photons 2000000]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from ringlight.core.simulate.photon import reflectance_run

CASES = {
    "MCML slab (Table 6.1)": dict(mua=10.0, mus=90.0, g=0.75, n=1.0, depth=0.02, reference=0.09739,
                                  mcml=(3.6e6, 4.2e6)),
    "matched isotropic half-space, albedo 0.9": dict(mua=0.1, mus=0.9, g=0.0, n=1.0, depth=math.inf,
                                                     reference=0.41495, mcml=(0.42e6, 0.60e6)),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--photons", type=int, default=2_000_000)
    args = parser.parse_args()
    volume = np.zeros((1, 1, 1), np.uint8)
    for name, case in CASES.items():
        mu_t = case["mua"] + case["mus"]
        tables = (np.array([mu_t]), np.array([case["mus"] / mu_t]), np.array([case["g"]]))
        reflectance_run(volume, *tables, mu_t, case["n"], case["depth"], 1000, 0, 0)
        photons = args.photons if case["g"] else args.photons // 4
        start = time.perf_counter()
        total, total_sq = reflectance_run(volume, *tables, mu_t, case["n"], case["depth"], photons, 1, 0)
        seconds = time.perf_counter() - start
        mean = total / photons
        error = math.sqrt((total_sq / photons - mean * mean) / photons)
        rate = photons / seconds
        low, high = case["mcml"]
        print(f"{name}")
        print(f"  reflectance {mean:.5f} +- {error:.5f} (published {case['reference']})")
        print(f"  {rate / 1e6:.2f} M photons/s on one core; MCML {low / 1e6:.2f}-{high / 1e6:.2f}; "
              f"ratio to MCML's best {rate / high:.2f}")


if __name__ == "__main__":
    main()
