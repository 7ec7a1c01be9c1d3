"""A fresh install's kernels compiled side by side, one process a core.

numba compiles each of ringlight's kernels the first time it runs and keeps it in its on-disk
cache, which later processes load from in about a second. A fresh install's first open compiled
the kernels an open and its first image need one after another: about 50 s on two cores, seen on
the demo dataset. That time is spread over some twenty kernels, none over 5 s, so it divides:
:func:`start_compiling` runs the warm-ups of the open's kernel groups (:data:`GROUPS`, each a
function that runs its kernels on tiny arrays of the types an open passes) in processes of their
own, which write numba's cache, while the caller goes on (an open reads its manifest meanwhile);
:meth:`Compilation.wait` waits for them, and the open then loads the kernels from the cache.
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

from .errors import ProgressCallback
from .rings.stacks import kernels_compiled

GROUPS = (
    "ringlight.core.dataset.warm_up:warm_up_batches",
    "ringlight.core.rings.stacks:warm_up_stack",
    "ringlight.core.dataset.warm_up:warm_up_frames",
    "ringlight.core.dataset.warm_up:warm_up_scatter",
    "ringlight.core.colour.display:warm_up_display",
    "ringlight.core.rings.coverage:warm_up_coverage",
)
"""The warm-ups of an open's kernels, ``module:function``, the longest to compile first (each
alone in a process with numba's cache empty: 13.7, 12.1, 10.4, 7.5, 4.5 and 3.4 s on two
cores, 0.8 s of each the imports; together what :func:`ringlight.core.rings.stacks.warm_up_kernels`
and :func:`ringlight.core.colour.display.warm_up_display` load, the rings' coverage, and a run of
files read)."""
MAX_PROCESSES = 4
"""Processes at most: the longest group (14 s) bounds the time from four on, the two shortest
following two others, and each process holds about 290 MB while it compiles."""
_LOCK = threading.Lock()
_running: Compilation | None = None


class Compilation:
    """The groups compiling in a pool of processes (made by :func:`start_compiling`)."""

    def __init__(self, pool: ProcessPoolExecutor):
        self._pool = pool
        self._futures = [pool.submit(_run_group, group) for group in GROUPS]

    def done(self) -> bool:
        """Whether every group has finished (or was dropped)."""
        return all(future.done() for future in self._futures)

    def wait(self, progress: ProgressCallback | None = None) -> bool:
        """Wait for the groups; returns whether they compiled. ``progress(fraction)`` after each
        (may raise ``Cancelled``: the groups not started are dropped, the running ones finish in
        the background). A group that failed in its process is left to the caller, which compiles
        it in-process when it runs it (and raises there); so is everything when the processes died."""
        try:
            for done, future in enumerate(as_completed(self._futures), 1):
                if not _compiled(future):
                    return False
                if progress is not None:
                    progress(done / len(self._futures))
        finally:
            self._pool.shutdown(wait=False, cancel_futures=True)
        return True


def start_compiling(workers: int | None = None) -> Compilation | None:
    """Where numba's cache lacks ringlight's kernels (a fresh install:
    :func:`~ringlight.core.rings.stacks.kernels_compiled`), start compiling :data:`GROUPS` in up to
    ``workers`` processes at once (default: one a core this process may run on, at most
    :data:`MAX_PROCESSES`). None where there is nothing to compile,
    with one core (where a process of its own gains nothing), or where processes cannot start.
    Threads that call it while a compilation runs get that one."""
    global _running
    count = min(len(GROUPS), workers or min(MAX_PROCESSES, _cores()))
    with _LOCK:
        if _running is not None and not _running.done():
            return _running
        if count < 2 or kernels_compiled():
            return None
        try:
            _running = Compilation(ProcessPoolExecutor(count, mp_context=multiprocessing.get_context("spawn")))
        except OSError:
            return None
        return _running


def compile_ahead(progress: ProgressCallback | None = None, workers: int | None = None) -> bool:
    """:func:`start_compiling`, then :meth:`Compilation.wait`: returns whether it compiled."""
    compilation = start_compiling(workers)
    return compilation is not None and compilation.wait(progress)


def _cores() -> int:
    """The cores this process may run on (its affinity where the platform says, as in a container
    limited to some)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _compiled(future: Future) -> bool:
    """Whether the pool still stands after ``future``'s group (which may have failed alone)."""
    try:
        future.result()
    except (BrokenProcessPool, OSError):
        return False
    except Exception:  # noqa: BLE001 - the caller compiles the group again, in-process, and reports it there
        pass
    return True


def _run_group(group: str) -> None:
    """Run the warm-up ``module:function`` (in a process of the pool)."""
    module, function = group.split(":")
    getattr(importlib.import_module(module), function)()
