"""Progress of the command-line tools: a tqdm bar on a terminal, log lines elsewhere.

When stderr is not a terminal (a batch job, a pipe), progress goes to the ``ringlight`` logger at
INFO level, a line every :data:`LOG_STEP` of the work; ``RINGLIGHT_LOG=info`` shows those lines on
stderr (:func:`configure_logging`).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

LOG_STEP = 0.1
"""Fraction of the work between two logged progress lines."""
logger = logging.getLogger("ringlight")


def configure_logging() -> None:
    """Send the ``ringlight`` logger to stderr at the level ``$RINGLIGHT_LOG`` names (default
    warning), with a time stamp."""
    level = os.environ.get("RINGLIGHT_LOG", "warning").upper()
    logger.setLevel(level if level in logging.getLevelNamesMapping() else "WARNING")
    if not any(getattr(handler, "ringlight", False) for handler in logger.handlers):
        handler = logging.StreamHandler()  # stderr as it is when a line is logged
        handler.setFormatter(logging.Formatter("%(asctime)s ringlight: %(message)s", "%H:%M:%S"))
        handler.ringlight = True
        logger.addHandler(handler)


@contextmanager
def progress_bar(description: str) -> Iterator[Callable[[float], None]]:
    """A progress callback taking fractions in [0, 1]: a tqdm bar on stderr when it is a terminal,
    else log lines (module docstring)."""
    if not sys.stderr.isatty():
        logged = [-1]

        def log(fraction: float) -> None:
            step = int(fraction / LOG_STEP + 1e-9)
            if step > logged[0]:
                logged[0] = step
                logger.info("%s: %3.0f%%", description, 100 * fraction)
        yield log
        return
    from tqdm import tqdm

    # No monitor thread: it would outlive the command when the CLI runs inside another program.
    tqdm.monitor_interval = 0
    with tqdm(total=1000, desc=description, file=sys.stderr, leave=False,
              bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]") as bar:
        def update(fraction: float) -> None:
            bar.update(int(round(fraction * 1000)) - bar.n)
        yield update
