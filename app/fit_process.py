"""The Layers tab's inverse fit in a child process, so that the GUI thread keeps its share of the GIL.

scipy's ``least_squares`` drives the fit from Python: every residual and Jacobian is Python and
numpy calls around the (GIL-free) compiled forward model, so a fit in a worker thread holds the
GIL most of the time, and the GUI thread gets it at the interpreter's switch interval at best and
much later on a loaded machine (issue 39: hundreds of 100-900 ms event-loop gaps during a fit;
``benchmarks/bench_fit_stutter.py`` measures them). In a process of its own the fit has its own
interpreter and GIL. The measured profile is taken in the worker thread (it reads the dataset,
which may be gigabytes in its store); only the profile (a few kB) goes to the child, and the
inversion comes back. The child is started with ``spawn`` (no fork of a process running Qt
threads), at a lower scheduling priority, and is terminated on cancel.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
from collections.abc import Callable

import numpy as np
from ringlight.core import Cancelled, ImpulseDataset, RinglightError
from ringlight.core.inversion.layers import Inversion, invert
from ringlight.core.inversion.report import DatasetInversion, invert_region
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.phases import phase, reporting_phases

POLL_S = 0.1
"""How often the worker thread looks for the child's messages and for a cancel."""
PROGRESS_STEP = 0.005
"""The child reports progress when it moved by this fraction (or named a new phase)."""
CHILD_NICENESS = 10
"""Added to the child's niceness (POSIX): on a loaded machine the scheduler serves the window's
process, which only draws, before the fit, which takes what is left."""


class FitProcessError(RinglightError):
    """The fit's process ended without a result (killed, out of memory)."""


def invert_region_apart(dataset: ImpulseDataset, region: np.ndarray, region_description: str,
                        settings: InversionSettings, progress: Callable[[float], None]) -> DatasetInversion:
    """:func:`ringlight.core.inversion.report.invert_region` with its fit in a child process.

    ``progress(fraction)`` is called in the calling thread; an exception from it (``Cancelled``)
    terminates the child and propagates.
    """
    return invert_region(dataset, region, region_description, settings,
                         fit=lambda *arguments: run_apart(invert, arguments[:3], progress))


def run_apart(fit: Callable[..., Inversion], arguments: tuple, progress: Callable[[float], None]) -> Inversion:
    """``fit(*arguments, progress)`` in a spawned child process (``fit`` and ``arguments``
    picklable; ``fit`` reports ``progress(fraction, what)``); returns its result or raises its
    error here. ``progress(fraction)`` is called here, at least every :data:`POLL_S`, so that a
    cancel (an exception from it) is seen; the child is then terminated."""
    context = multiprocessing.get_context("spawn")
    messages = context.Queue()
    child = context.Process(target=_child, args=(fit, arguments, messages), name="ringlight fit", daemon=True)
    child.start()
    fraction = 0.0
    try:
        while True:
            try:
                kind, value = messages.get(timeout=POLL_S)
            except queue.Empty:
                progress(fraction)  # raises once cancelled
                if not child.is_alive() and messages.empty():
                    raise FitProcessError(f"the fit's process ended without a result (exit code {child.exitcode})")
                continue
            if kind == "progress":
                fraction = value
                progress(fraction)
            elif kind == "phase":
                phase(value)
            elif kind == "result":
                return value
            else:
                raise value
    finally:
        if child.is_alive():
            child.terminate()
        child.join()
        messages.close()
        messages.join_thread()


def _child(fit: Callable[..., Inversion], arguments: tuple, messages) -> None:
    """The child process: run ``fit`` and put its progress, phases and result (or error) on
    ``messages``."""
    if hasattr(os, "nice"):
        os.nice(CHILD_NICENESS)  # the window's process goes first when the cores are busy
    last = [-1.0]

    def progress(fraction: float, what: str = "") -> None:
        if fraction - last[0] >= PROGRESS_STEP or fraction >= 1.0:
            last[0] = fraction
            messages.put(("progress", float(fraction)))

    try:
        with reporting_phases(lambda name: messages.put(("phase", name))):
            result = fit(*arguments, progress)
    except (RinglightError, Cancelled) as error:
        messages.put(("error", error))
    except MemoryError:
        messages.put(("error", FitProcessError("the fit ran out of memory")))
    except Exception as error:  # a bug: its message and type, as the job slot reports one
        messages.put(("error", RuntimeError(f"{type(error).__name__}: {error}")))
    else:
        messages.put(("result", result))
