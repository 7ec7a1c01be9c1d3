"""Running slow work off the GUI thread, with progress, cancel and supersession.

A job is a plain function ``work(progress) -> result`` that captured all its inputs (a frozen
request, napari style). ``progress(fraction)`` reports to the GUI and raises
:class:`~ringlight.core.Cancelled` once the job was cancelled, so core loops stop at their next
progress report and leave nothing half-written. Results and errors come back through queued
signals, so they are handled in the GUI thread.

The phase a job names (:func:`ringlight.core.phases.phase`) comes back as a signal too.

Each :class:`JobSlot` runs one kind of job (loading, stacks, exports): starting a new job in a
slot cancels the one running there, and a superseded job's result is dropped.
"""

from __future__ import annotations

import threading
import traceback
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, QRunnable, QThreadPool, Signal
from ringlight.core import Cancelled, RinglightError
from ringlight.core.phases import reporting_phases

Work = Callable[[Callable[[float], None]], Any]


class _JobSignals(QObject):
    progress = Signal(int, float)
    phase = Signal(int, str)
    finished = Signal(int, object)
    failed = Signal(int, str)
    cancelled = Signal(int)


class _Job(QRunnable):
    """One run of ``work`` in a pool.

    PySide keeps the Python object of a started runnable alive until the pool deletes it, and at
    times later than that (seen under pytest-xdist: a failed open's job, seconds after the pool was
    idle); the job lets go of ``work``, the closure that holds its window, as soon as it runs, so
    that such a job keeps no closed window alive.
    """

    def __init__(self, number: int, work: Work, signals: _JobSignals):
        super().__init__()
        self.setAutoDelete(True)
        self.number = number
        self.work = work
        self.signals = signals
        self.cancel_event = threading.Event()

    def report(self, fraction: float) -> None:
        if self.cancel_event.is_set():
            raise Cancelled("cancelled")
        self.signals.progress.emit(self.number, float(fraction))

    def run(self) -> None:
        work, self.work = self.work, None  # a finished job holds nothing of its window (class docstring)
        try:
            if self.cancel_event.is_set():
                raise Cancelled("cancelled")
            with reporting_phases(lambda name: self.signals.phase.emit(self.number, name)):
                result = work(self.report)
        except Cancelled:
            self.signals.cancelled.emit(self.number)
        except RinglightError as error:
            self.signals.failed.emit(self.number, str(error))
        except MemoryError:
            self.signals.failed.emit(self.number, "out of memory")
        except Exception as error:  # a bug: report it with its traceback instead of crashing Qt
            self.signals.failed.emit(self.number, f"internal error: {error!r}\n{traceback.format_exc()}")
        else:
            self.signals.finished.emit(self.number, result)


class JobSlot(QObject):
    """One kind of background job at a time.

    Signals carry only the current job's events: ``started(str)`` with its description,
    ``progress(float)``, ``phase(str)`` with the phase it names, ``finished(object)`` with its result, ``failed(str)`` with a one-line
    message, ``cancelled()``, and ``idle()`` after any of the last three.
    """

    started = Signal(str)
    progress = Signal(float)
    phase = Signal(str)
    finished = Signal(object)
    failed = Signal(str)
    cancelled = Signal()
    idle = Signal()

    def __init__(self, pool: QThreadPool, parent: QObject | None = None):
        super().__init__(parent)
        self._pool = pool
        self._signals = _JobSignals(self)
        self._signals.progress.connect(self._on_progress)
        self._signals.phase.connect(self._on_phase)
        self._signals.finished.connect(self._on_finished)
        self._signals.failed.connect(self._on_failed)
        self._signals.cancelled.connect(self._on_cancelled)
        self._count = 0
        self._current: _Job | None = None
        self._closed = False

    @property
    def busy(self) -> bool:
        return self._current is not None

    def start(self, description: str, work: Work) -> None:
        """Run ``work`` in the pool, cancelling and superseding any job running here; nothing
        once the slot is closed."""
        if self._closed:
            return
        self.cancel()
        self._count += 1
        self._current = _Job(self._count, work, self._signals)
        self.started.emit(description)
        self._pool.start(self._current)

    def cancel(self) -> None:
        """Ask the current job to stop at its next progress report; its result is dropped."""
        if self._current is not None:
            self._current.cancel_event.set()
            self._current = None
            self.cancelled.emit()
            self.idle.emit()

    def close(self) -> None:
        """Cancel the current job and refuse new ones: for a window going away, whose widgets
        may still emit the signals that start jobs while they are destroyed (a job started then
        could outlive the libraries it uses, whose exit-time clean-up has run)."""
        self._closed = True
        self.cancel()

    def _is_current(self, number: int) -> bool:
        return self._current is not None and self._current.number == number

    def _on_progress(self, number: int, fraction: float) -> None:
        if self._is_current(number):
            self.progress.emit(fraction)

    def _on_phase(self, number: int, name: str) -> None:
        if self._is_current(number):
            self.phase.emit(name)

    def _on_finished(self, number: int, result: object) -> None:
        if self._is_current(number):
            self._current = None
            self.finished.emit(result)
            self.idle.emit()

    def _on_failed(self, number: int, message: str) -> None:
        if self._is_current(number):
            self._current = None
            self.failed.emit(message)
            self.idle.emit()

    def _on_cancelled(self, number: int) -> None:
        if self._is_current(number):
            self._current = None
            self.cancelled.emit()
            self.idle.emit()
