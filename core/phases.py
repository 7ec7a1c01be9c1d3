"""Naming the phase of long work beside its progress fraction.

Long work reports how far it is through a :data:`~.errors.ProgressCallback` (a fraction); which
phase it is in ("reading the frames, band 2 of 5", "writing the store", "computing the stacks")
it names with :func:`phase`. The name goes to the reporter that whoever runs the work set with
:func:`reporting_phases`: the explorer's job slot shows it beside its bar, the command line's
progress bar in its description. A context variable holds the reporter, so each thread (each
worker) has its own, work run without one names nothing, and no signature of the work changes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

_reporter: ContextVar[Callable[[str], None] | None] = ContextVar("ringlight_phase_reporter", default=None)


def phase(name: str) -> None:
    """Say that the work running in this thread is now in phase ``name`` (a few lower-case words,
    no full stop)."""
    reporter = _reporter.get()
    if reporter is not None:
        reporter(name)


@contextmanager
def reporting_phases(reporter: Callable[[str], None]) -> Iterator[None]:
    """Within the block, :func:`phase` calls of this thread go to ``reporter(name)``."""
    token = _reporter.set(reporter)
    try:
        yield
    finally:
        _reporter.reset(token)
