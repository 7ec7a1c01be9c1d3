"""Report on the bundled samples as the explorer first shows them (issue 12's closing figures).

For each sample: the time to open it from an empty user cache (write the dataset, compute the
default stacks: what a fresh ``ringlight`` does before its first picture), the noise of T_r per
radius stored with the sample, and the explorer's own correlation (zero-mean NCC) of each T_r with
the path-length ground truth of its nearest bin.

    python tools/sample_report.py [NAME ...]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from ringlight.app.session import load_for_viewing
from ringlight.core.simulate.samples import SAMPLES, load_sample


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("names", nargs="*", default=list(SAMPLES))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        os.environ["RINGLIGHT_CACHE_DIR"] = cache
        for name in args.names:
            started = time.perf_counter()
            loaded = load_for_viewing(None, None, lambda fraction: None, sample=name)
            seconds = time.perf_counter() - started
            _, noise = load_sample(name)
            stacks = loaded.stacks
            print(f"{name}: opened from an empty cache in {seconds:.1f} s")
            print("  r      " + " ".join(f"{r:6.0f}" for r in stacks.pair.radii))
            print("  noise  " + " ".join(f"{noise[int(r)]:6.3f}" if int(r) < len(noise) else "     -"
                                         for r in stacks.pair.radii))
            print("  NCC    " + " ".join(f"{c:6.3f}" for c in stacks.correlations))


if __name__ == "__main__":
    main()
