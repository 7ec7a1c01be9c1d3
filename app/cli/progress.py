"""Progress bars of the command-line tools (tqdm on stderr, terminals only)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager


@contextmanager
def progress_bar(description: str) -> Iterator[Callable[[float], None]]:
    """A tqdm bar on stderr (shown on terminals only) driven by fractions in [0, 1]."""
    from tqdm import tqdm

    # No monitor thread: it would outlive the command when the CLI runs inside another program.
    tqdm.monitor_interval = 0
    with tqdm(total=1000, desc=description, file=sys.stderr, disable=None, leave=False,
              bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]") as bar:
        def update(fraction: float) -> None:
            bar.update(int(round(fraction * 1000)) - bar.n)
        yield update
