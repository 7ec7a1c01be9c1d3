"""Test setup: offscreen Qt, private cache and settings folders, and a guard against leaks.

The leak guard (napari's and silx's habit) fails a test that leaves behind a top-level widget,
an active QTimer, a running QThreadPool job or a Python thread. Qt is inspected only once a
test module has imported it, so tests that never touch Qt do not import it.
"""

import gc
import re
import os
import shutil
import sys
import threading
import time
import types

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# numba's parallel kernels run on OpenMP, whose idle threads spin between the suite's many small
# kernel calls, taking the core from the other test workers (one per core): sleeping instead cut
# the user CPU time of test_stacks, test_rings and test_coverage by 10-20 % in one process, and
# the CPU of four such files under two workers by 6 %. Set before the first
# parallel kernel loads OpenMP; subprocesses inherit it. Results do not depend on it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest

GRACE_S = 5.0
"""How long finished work may take to wind down after a test before it counts as leaked."""


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    """Point ringlight's user cache at a fresh folder for every test."""
    folder = tmp_path_factory.mktemp("user-cache")
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(folder))
    return folder


@pytest.fixture(scope="session")
def sample_originals(tmp_path_factory):
    """``sample_originals(name)``: bundled sample ``name`` written as a dataset once per test run
    (layers3 and skin1 hold 5000 frames, 60 MB: layers3 takes 12 CPU-s), for :func:`place_sample`
    to copy and :func:`link_sample` to link to.

    pytest-xdist's workers share them (each wrote its own before: layers3 up to four times): a
    sample is written in the worker's own folder, then renamed into the run's shared one, which is
    atomic. A worker that finds it there uses it; one that loses a race to rename uses the winner's."""
    from ringlight.core.simulate.samples import sample_dataset

    own = tmp_path_factory.getbasetemp()
    # Each xdist worker's base folder lies in the run's own (pytest-N); without xdist, the
    # process's base folder is the run's.
    shared = (own.parent if os.environ.get("PYTEST_XDIST_WORKER") else own) / "sample-originals"
    shared.mkdir(exist_ok=True)

    def original(name: str):
        published = shared / name
        if not published.exists():
            folder = tmp_path_factory.mktemp(f"sample-{name}")
            with pytest.MonkeyPatch.context() as patch:
                patch.setenv("RINGLIGHT_CACHE_DIR", str(folder))
                written = sample_dataset(name)
            try:
                os.rename(written, published)
            except OSError:
                if not published.is_dir():  # not another worker's copy: a real failure
                    raise
        return published

    return original


@pytest.fixture(scope="session")
def place_sample(sample_originals):
    """``place_sample(name)``: put bundled sample ``name`` into the user cache now in effect (the
    folder ``sample_dataset(name)`` returns) as its first use would write it: a copy of the files
    of :func:`sample_originals` (real copies: a hard link would change the shared files' ctime,
    which is part of every store's key). Returns the folder. For tests of what a sample holds, not
    of how it is written (those are tests/test_samples.py's and the demo command's)."""
    from ringlight.core.dataset.cache import CACHE_FOLDER_NAME
    from ringlight.core.simulate.samples import sample_folder

    def place(name: str):
        target = sample_folder(name)
        if not target.exists():
            shutil.copytree(sample_originals(name), target, ignore=shutil.ignore_patterns(CACHE_FOLDER_NAME))
        return target

    return place


@pytest.fixture
def link_sample(sample_originals):
    """``link_sample(name)``: bundled sample ``name`` in the user cache now in effect (where
    ``sample_dataset(name)`` finds it) as a symbolic link to :func:`sample_originals`' folder, for
    tests that only read a sample: its frames are not copied (layers3's 5000 took 4 s of the
    kernel's time here, each time) and its store is made once for the run, by the first test that
    opens it (in the shared folder: ringlight's caches are written for processes that share a
    dataset). Tests of a first open, or that write into the sample, use :func:`place_sample`.
    Returns the folder."""
    from ringlight.core.simulate.samples import sample_folder

    def link(name: str):
        target = sample_folder(name)
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(sample_originals(name), target_is_directory=True)
        return target

    return link


@pytest.fixture(autouse=True, scope="session")
def private_settings(tmp_path_factory):
    """The folder that holds every QSettings the tests create without naming a file."""
    folder = tmp_path_factory.mktemp("qt-settings")
    os.environ["XDG_CONFIG_HOME"] = str(folder)  # Qt on Linux, and subprocesses, read it
    return folder


@pytest.fixture(autouse=True)
def settings_in_private_folder(private_settings):
    """Redirect QSettings of both scopes to the private folder once Qt is loaded.

    Setting the environment alone misses macOS and Windows, whose native settings are not
    files, so the default format becomes INI there too.
    """
    if "PySide6.QtCore" in sys.modules:
        from PySide6.QtCore import QSettings

        QSettings.setDefaultFormat(QSettings.Format.IniFormat)
        for scope in QSettings.Scope.UserScope, QSettings.Scope.SystemScope:
            QSettings.setPath(QSettings.Format.IniFormat, scope, str(private_settings))


_LIBRARY_THREADS = re.compile(r"zarr_io|asyncio_\d+")
"""zarr's event loop and its executor: started on first use, kept for the process by design."""


def _threads() -> set:
    """Python threads now, except the dummies Python makes for foreign (Qt pool) threads and the
    process-wide threads of :data:`_LIBRARY_THREADS`.

    Those are covered by the pool check, and a dummy can be neither joined nor retired.
    """
    return {thread for thread in threading.enumerate()
            if not isinstance(thread, threading._DummyThread) and not _LIBRARY_THREADS.fullmatch(thread.name)}


def _qt_state():
    """Top-level widgets, active QTimers and busy QThreadPools by id, or None before Qt runs.

    Timers are found both among the children of the application and of each window (also those
    made in C++) and among all Python-made Qt objects (also timers without a parent).
    """
    if "PySide6.QtWidgets" not in sys.modules:
        return None
    from PySide6.QtCore import QThreadPool, QTimer
    from PySide6.QtWidgets import QApplication
    from shiboken6 import Shiboken

    app = QApplication.instance()
    if app is None:
        return None
    widgets = app.topLevelWidgets()
    wrapped = Shiboken.getAllValidWrappers()
    timers = [*app.findChildren(QTimer), *[t for w in widgets for t in w.findChildren(QTimer)],
              *[t for t in wrapped if isinstance(t, QTimer)]]
    pools = [QThreadPool.globalInstance(), *[p for p in wrapped if isinstance(p, QThreadPool)]]
    return ({id(w): w for w in widgets}, {id(t): t for t in timers if t.isActive()},
            {id(p): p for p in pools if p.activeThreadCount() > 0})


def _settle_qt(deadline: float):
    """Let pool jobs finish, deferred deletes happen and single-shot timers fire until ``deadline``.

    Returns the state of :func:`_qt_state` then, or None while there is no QApplication.
    """
    from PySide6.QtCore import QCoreApplication, QEvent

    while QCoreApplication.instance() is not None:
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
        QCoreApplication.processEvents()
        state = _qt_state()
        if not (state[1] or state[2]) or time.monotonic() > deadline:
            return state
        time.sleep(0.01)
    return None


def _holders(obj, bookkeeping: tuple, depth: int = 16) -> str:
    """The chain of Python objects that keep ``obj`` alive, outermost last (a dict is named by the
    key that holds the object): at each step the first referrer that is not a container, or else
    the first container, leaving out frames and the guard's own ``bookkeeping`` containers.
    ``gc.get_referrers`` does not see frozen objects (:func:`pytest_collection_finish`: a test
    module's globals among them): they are unfrozen for the search, and frozen again after it."""
    gc.unfreeze()
    try:
        return _holder_chain(obj, bookkeeping, depth)
    finally:
        gc.freeze()


def _holder_chain(obj, bookkeeping: tuple, depth: int) -> str:
    chain, seen = [], {id(obj), *map(id, bookkeeping)}
    for _ in range(depth):
        referrers = [r for r in gc.get_referrers(obj) if id(r) not in seen and not isinstance(r, types.FrameType)]
        seen.add(id(referrers))
        if not referrers:
            break
        holder = next((r for r in referrers if not isinstance(r, (dict, list, tuple))), referrers[0])
        seen.add(id(holder))
        name = type(holder).__qualname__
        function = getattr(holder, "__func__", holder)
        if isinstance(function, types.FunctionType):
            name += f" {function.__qualname__}"
        if isinstance(holder, types.ModuleType):  # a module's global: nothing further to find
            chain.append(f"module {holder.__name__}")
            break
        for key, value in holder.items() if isinstance(holder, dict) else ():  # no comprehension: it
            if value is obj:  # would hold ``obj`` in a cell
                name += f"[{key!r}]"
                break
        chain.append(name)
        obj = holder
    return " <- ".join(chain) or "nothing Python can see (a C++ owner)"


def _new(after: dict, before: dict) -> list:
    return [item for key, item in after.items() if key not in before]


@pytest.fixture(autouse=True)
def no_leaks(request):
    """Fail the test if it leaves widgets, timers, pool jobs or threads behind."""
    threads_before = _threads()
    qt_before = _settle_qt(time.monotonic()) if "PySide6.QtWidgets" in sys.modules else None
    yield
    if request.node.get_closest_marker("allow_leaks") or getattr(request.node, "call_failed", False):
        return  # a failed test's traceback keeps its objects alive: its failure says enough
    # pytest drops the test's fixture values only after teardown; what they alone keep alive (the
    # parentless menus of a closed window's plots) must go now to tell it from a leak.
    getattr(request.node, "funcargs", {}).clear()
    deadline = time.monotonic() + GRACE_S
    problems = []
    for thread in _threads() - threads_before:
        thread.join(max(0.0, deadline - time.monotonic()))
        if thread.is_alive():
            problems.append(f"thread {thread.name!r}")
    qt_after = _settle_qt(deadline) if "PySide6.QtWidgets" in sys.modules else None
    # Widgets that only garbage cycles keep (a plot's parentless menus) go once the cycles are
    # collected; collect until none is new or the grace period is over, as a worker that has just
    # ended may drop its last reference to them a moment after its pool reports it idle.
    while qt_after is not None and _new(qt_after[0], qt_before[0] if qt_before else {}):
        qt_after = None  # hold no wrapper while the cycles that may own the widgets are collected
        gc.collect()
        expired = time.monotonic() > deadline
        if not expired:
            time.sleep(0.05)
        qt_after = _settle_qt(deadline)
        if expired:
            break
    if qt_after is not None:
        widgets_before, timers_before, pools_before = qt_before or ({}, {}, {})
        widgets, timers, pools = qt_after
        leaked = _new(widgets, widgets_before)
        problems += [f"top-level widget {type(w).__name__} {w.objectName()!r}" for w in leaked[:5]]
        if len(leaked) > 5:
            problems.append(f"{len(leaked) - 5} more top-level widgets")
        if leaked:
            problems.append("the first is held by " + _holders(leaked[0], (leaked, widgets, qt_after)))
        problems += [f"active QTimer {t.objectName()!r} of {type(t.parent()).__name__ if t.parent() else 'no parent'}"
                     for t in _new(timers, timers_before)]
        problems += [f"QThreadPool with {p.activeThreadCount()} running job(s)" for p in _new(pools, pools_before)]
    if problems:
        pytest.fail("left alive after the test: " + "; ".join(problems), pytrace=False)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.when == "call":
        item.call_failed = report.failed
    return report


def pytest_configure(config):
    config.addinivalue_line("markers", "allow_leaks(reason): the test deliberately leaves work running")
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        # On a fresh clone numba's cache is empty and every worker compiled the kernels of an open
        # as its first test ran (all four alike); compiled first, side by side, they are loaded.
        from ringlight.core.compile_ahead import compile_ahead

        compile_ahead()


def pytest_collection_finish(session):
    """Put what collecting imported (numpy, numba, SciPy, Qt, pyqtgraph, colour-science: the test
    modules import them) out of the cyclic collector's sight, as the app does at start-up
    (:func:`ringlight.app.heap.settle_heap`). :func:`no_leaks` collects in full after every test that
    leaves a window's widgets to the collector; each such collection scanned them all: 0.16 s a
    test in tests/test_window.py (31 collections, 5.0 s of its 62 s under cProfile), 0.06 s with
    them frozen (2.0 s). Frozen objects are still freed by reference counting."""
    from ringlight.app.heap import settle_heap  # imports gc alone: the OpenEXR floor's venv has no Qt or OpenCV

    settle_heap()


@pytest.fixture
def window(qtbot, tmp_path):
    """The explorer's main window at 1366 x 768, shown and active, its settings in ``tmp_path``
    (Qt is imported here, only by the tests that ask for a window; a module may define its own)."""
    from plain_view import plain_settings
    from ringlight.app.window import MainWindow

    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    window.resize(1366, 768)
    window.show()
    qtbot.waitExposed(window)
    window.activateWindow()
    yield window
    window.shutdown()
