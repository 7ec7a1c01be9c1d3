"""The inverse fit runs in a child process (issue 39: the window stuttered while a fit held the
GIL in a worker thread): the work runs in another process, progress and phases come back, a
cancel terminates it, and errors come back as ours."""

from __future__ import annotations

import multiprocessing
import os
import time

import pytest
from ringlight.app.fit_process import CHILD_NICENESS, FitProcessError, run_apart
from ringlight.core import Cancelled
from ringlight.core.inversion.layers import InversionError
from ringlight.core.phases import phase, reporting_phases


def report_pid(steps, progress):
    """A stand-in fit: reports ``steps`` fractions and a phase, returns its process id and
    niceness."""
    phase("fitting the stand-in")
    for step in range(1, steps + 1):
        progress(step / steps, "stand-in")
    return os.getpid(), os.nice(0)


def never_ends(progress):
    while True:
        progress(0.5, "waiting")
        time.sleep(0.01)


def refuses(progress):
    raise InversionError("the region's profile holds no values")


def dies(progress):
    os._exit(3)


def test_the_fit_runs_in_another_process_and_reports_its_progress_and_phases():
    fractions, phases = [], []
    with reporting_phases(phases.append):
        pid, niceness = run_apart(report_pid, (4,), fractions.append)
    assert pid != os.getpid()
    assert niceness == os.nice(0) + CHILD_NICENESS or niceness == 19  # lower priority (19 at most)
    assert [f for f in fractions if f in (0.25, 0.5, 0.75, 1.0)] == [0.25, 0.5, 0.75, 1.0]
    assert phases == ["fitting the stand-in"]
    assert multiprocessing.active_children() == []


def test_a_cancel_terminates_the_fit_process():
    def progress(fraction):
        raise Cancelled("cancelled")

    with pytest.raises(Cancelled):
        run_apart(never_ends, (), progress)
    assert multiprocessing.active_children() == []  # terminated and joined, not left running


def test_the_fit_s_own_error_comes_back_as_itself():
    with pytest.raises(InversionError, match="the region's profile holds no values"):
        run_apart(refuses, (), lambda fraction: None)


def test_a_fit_process_that_dies_is_one_line_not_a_hang():
    with pytest.raises(FitProcessError, match=r"ended without a result \(exit code 3\)"):
        run_apart(dies, (), lambda fraction: None)
