"""Test setup: offscreen Qt, private cache and settings folders, and a guard against leaks.

The leak guard (napari's and silx's habit) fails a test that leaves behind a top-level widget,
an active QTimer, a running QThreadPool job or a Python thread. Tests that never touch Qt do not
import it.
"""

import gc
import os
import sys
import threading
import time

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import pytest

GRACE_S = 5.0
"""How long finished work may take to wind down after a test before it counts as leaked."""


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    """Point ringlight's user cache at a fresh folder for every test."""
    folder = tmp_path_factory.mktemp("user-cache")
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(folder))
    return folder


@pytest.fixture(autouse=True, scope="session")
def private_settings(tmp_path_factory):
    """QSettings of every scope and format live in a temporary folder, never the user's."""
    folder = tmp_path_factory.mktemp("qt-settings")
    os.environ["XDG_CONFIG_HOME"] = str(folder)  # where Qt on Linux keeps native settings
    yield folder


def _qt_state():
    """Top-level widgets and active QTimers now, or None when Qt is not loaded."""
    if "PySide6.QtWidgets" not in sys.modules:
        return None
    from PySide6.QtCore import QCoreApplication, QEvent, QThreadPool, QTimer
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance()
    if app is None:
        return None
    QThreadPool.globalInstance().waitForDone(int(GRACE_S * 1000))
    for _ in range(3):
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
        app.processEvents()
    widgets = {id(w): w for w in app.topLevelWidgets() if not w.property("ringlight_leak_ok")}
    timers = [t for t in app.findChildren(QTimer) if t.isActive()]
    for widget in widgets.values():
        timers += [t for t in widget.findChildren(QTimer) if t.isActive()]
    return widgets, {id(t): t for t in timers}


def _running_pools():
    """QThreadPools that still have running jobs (each pool's own count)."""
    if "PySide6.QtCore" not in sys.modules:
        return []
    from PySide6.QtCore import QThreadPool

    return [pool for pool in gc.get_objects() if isinstance(pool, QThreadPool) and _alive(pool)
            and pool.activeThreadCount() > 0]


def _alive(qobject) -> bool:
    from shiboken6 import isValid

    return isValid(qobject)


@pytest.fixture(autouse=True)
def no_leaks(request):
    """Fail the test if it leaves widgets, timers, pool jobs or threads behind."""
    threads_before = set(threading.enumerate())
    pools_before = {id(pool) for pool in _running_pools()}
    qt_before = _qt_state()
    yield
    if request.node.get_closest_marker("allow_leaks"):
        return
    problems = []
    deadline = time.monotonic() + GRACE_S
    for thread in set(threading.enumerate()) - threads_before:
        thread.join(max(0.0, deadline - time.monotonic()))
        if thread.is_alive():
            problems.append(f"thread {thread.name!r}")
    qt_after = _qt_state()
    if qt_after is not None:
        widgets_before, timers_before = qt_before or ({}, {})
        widgets, timers = qt_after
        problems += [f"top-level widget {type(w).__name__} {w.objectName()!r}" for key, w in widgets.items()
                     if key not in widgets_before and w.isVisible()]
        problems += [f"active QTimer {t.objectName()!r} of {type(t.parent()).__name__}" for key, t in timers.items()
                     if key not in timers_before]
        for pool in _running_pools():
            if id(pool) not in pools_before and not pool.waitForDone(int(max(0.0, deadline - time.monotonic()) * 1000)):
                problems.append(f"QThreadPool with {pool.activeThreadCount()} running job(s)")
    if problems:
        pytest.fail("left alive after the test: " + "; ".join(problems), pytrace=False)


def pytest_configure(config):
    config.addinivalue_line("markers", "allow_leaks(reason): the test deliberately leaves work running")
