"""The maps' node fits against the full fit on the optics benchmark's map (not a test: prints figures).

Fits every pixel and channel of ``benchmarks/bench_optics.py``'s map (SIZE x SIZE, the maps' own
model response of mus' 0.2, mua 0.01 per grid step, 3 % noise on every response value, max_radius
8) from its ring stack and ring-spread errors twice, by the node steps (the maps' estimator) and by
the full Levenberg-Marquardt fit on the table's splines (the reference), and prints where they
differ: the statuses, u = log mus and v = log (mua / mus) in the full fit's standard errors (the
largest and the RMS), the standard errors' largest relative difference, the correlation's largest
difference, and the share of node fits by the node steps they took (0: the full fit's).

    python tools/node_fit_agreement.py [--size 800]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ringlight.core.optics.maps import MODEL_FLOOR, error_freedom, profile_radii, t_inflation
from ringlight.core.optics.pixel_fit import CONVERGED, fit_profiles
from ringlight.core.optics.synthetic import homogeneous_dataset
from ringlight.core.optics.table import table_for
from ringlight.core.rings.stack_spread import ring_stack_and_errors

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_optics import model_kernel  # noqa: E402 - the benchmark's map, as it makes it


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=800)
    args = parser.parse_args()
    table = table_for(1.4, 0.0, np.arange(0.0, 8.0), photons=1_000_000)  # cached: made once per n and g
    dataset = homogeneous_dataset(model_kernel(table, 8, 0.2, 0.01), args.size, args.size, max_radius=8.0,
                                  member_noise=np.full(9, 0.03), n=1.4, g=0.0)
    radii = profile_radii(dataset)
    stack, errors = ring_stack_and_errors(dataset, radii)
    inflation = t_inflation(error_freedom(dataset, radii, "ring spread"))
    fits = {estimator: fit_profiles(table, stack.images, errors, np.ones(3), counts=stack.counts, floor=MODEL_FLOOR,
                                    inflation=inflation, estimator=estimator) for estimator in ("nodes", "full")}
    nodes, full = fits["nodes"], fits["full"]
    print(f"{nodes['status'].size} fits; the same status everywhere: {np.array_equal(nodes['status'], full['status'])}")
    done = full["status"] == CONVERGED
    for name, variance in (("u", "cuu"), ("v", "cvv")):
        difference = (nodes[name] - full[name])[done] / np.sqrt(full[variance][done])
        error_ratio = np.sqrt(nodes[variance][done] / full[variance][done]) - 1
        print(f"{name}: within {np.abs(difference).max():.4f} of a standard error (RMS "
              f"{np.sqrt(np.mean(difference ** 2)):.4f}); standard errors within "
              f"{100 * np.abs(error_ratio).max():.2f} %")
    correlation = (nodes["cuv"] - full["cuv"])[done] / np.sqrt(full["cuu"] * full["cvv"])[done]
    print(f"correlation within {np.abs(correlation).max():.4f}")
    shares = np.bincount(nodes["node_steps"].ravel(), minlength=3) / nodes["node_steps"].size
    print("node fits by node steps taken (0: the full fit's): "
          + ", ".join(f"{steps}: {100 * share:.2f} %" for steps, share in enumerate(shares)))


if __name__ == "__main__":
    main()
