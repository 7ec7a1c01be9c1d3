"""Progress of the command-line tools: a tqdm bar on a terminal, log lines elsewhere.

When stderr is not a terminal (a batch job, a pipe), progress goes to the ``ringlight`` logger, a
line every :data:`LOG_STEP` of the work and at least one every :data:`HEARTBEAT_S` while it runs
(:func:`configure_logging` sends the logger to stderr). With ``RINGLIGHT_LOG=info`` every line
shows from the start, at INFO level; by default (warning) work that runs past :data:`QUIET_S`
says so from then on, at WARNING level: ``simulate`` and ``layers --method inverse`` said nothing
for minutes in a batch job (issue 39), while a short command's stderr stays its result or its one
line of error. ``RINGLIGHT_LOG=error`` silences them all.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from time import monotonic
from typing import TextIO

from ringlight.core.phases import reporting_phases

LOG_STEP = 0.1
"""Fraction of the work between two logged progress lines."""
HEARTBEAT_S = 60.0
"""Seconds after which a progress line is logged even within a step (slow work still says so)."""
QUIET_S = 60.0
"""Seconds of work after which its progress shows without ``RINGLIGHT_LOG=info``."""
logger = logging.getLogger("ringlight")


def configure_logging() -> None:
    """Send the ``ringlight`` logger to stderr (:func:`stderr_copy`) at the level
    ``$RINGLIGHT_LOG`` names (default warning), with a time stamp.

    Called by every command: in one process (a notebook or a test calling ``main`` again) the
    handler follows ``sys.stderr`` when that is another stream than the one it was made for, which
    may be closed by then (a line logged there was a logging error's traceback)."""
    level = os.environ.get("RINGLIGHT_LOG", "warning").upper()
    logger.setLevel(level if level in logging.getLevelNamesMapping() else "WARNING")
    for handler in [handler for handler in logger.handlers if getattr(handler, "ringlight", None) is not None]:
        if handler.ringlight is sys.stderr:
            return
        logger.removeHandler(handler)
        if handler.stream is not handler.ringlight:  # its own duplicate of the descriptor
            handler.stream.close()
    handler = logging.StreamHandler(stderr_copy())
    handler.setFormatter(logging.Formatter("%(asctime)s ringlight: %(message)s", "%H:%M:%S"))
    handler.ringlight = sys.stderr  # the stream it was made for
    logger.addHandler(handler)


def stderr_copy() -> TextIO:
    """A line-buffered stream on a duplicate of standard error's file descriptor (``sys.stderr``
    itself when it has none).

    Progress must not go through descriptor 2: while a frame decodes, the damaged-file chatter of
    the OpenEXR library is silenced by pointing descriptor 2 at /dev/null
    (:func:`ringlight.core.dataset.exr_header.quiet_library`), and during an open the reader
    threads decode frames back to back, so lines written meanwhile were lost (3 of the 11 lines
    of a 256 px open: 30 %, 40 % and 70 %). The duplicate keeps pointing at the real stderr."""
    try:
        descriptor = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # a stream without a descriptor (an IDE, a test)
        return sys.stderr
    return os.fdopen(os.dup(descriptor), "w", buffering=1, encoding=sys.stderr.encoding, errors="backslashreplace")


@contextmanager
def progress_bar(description: str) -> Iterator[Callable[[float], None]]:
    """A progress callback taking fractions in [0, 1]: a tqdm bar on stderr when it is a terminal,
    else log lines (module docstring). The phase the work names (:mod:`ringlight.core.phases`)
    follows the description: in the bar's, or a log line each."""
    if not sys.stderr.isatty():
        logged = [-1]
        named = [description]
        started = monotonic()
        last = [started]

        def say(*message) -> None:
            """Log at INFO where that shows, else at WARNING once the work ran past QUIET_S."""
            if logger.isEnabledFor(logging.INFO):
                logger.info(*message)
            elif monotonic() - started >= QUIET_S:
                logger.warning(*message)

        def log(fraction: float) -> None:
            step = int(fraction / LOG_STEP + 1e-9)
            if step > logged[0] or monotonic() - last[0] >= HEARTBEAT_S:
                logged[0] = max(step, logged[0])
                last[0] = monotonic()
                say("%s: %3.0f%%", named[0], 100 * fraction)

        def name_phase(name: str) -> None:
            if f"{description}: {name}" != named[0]:
                named[0] = f"{description}: {name}"
                say("%s", named[0])
        with reporting_phases(name_phase):
            yield log
        return
    from tqdm import tqdm

    # No monitor thread: it would outlive the command when the CLI runs inside another program.
    tqdm.monitor_interval = 0
    stream = stderr_copy()
    try:
        with tqdm(total=1000, desc=description, file=stream, leave=False,
                  bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]") as bar:
            def update(fraction: float) -> None:
                bar.update(int(round(fraction * 1000)) - bar.n)
            with reporting_phases(lambda name: bar.set_description_str(f"{description}: {name}")):
                yield update
    finally:
        if stream is not sys.stderr:
            stream.close()
