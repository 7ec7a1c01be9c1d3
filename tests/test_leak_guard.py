"""The conftest's leak guard fails tests that leave widgets, timers, pool jobs or threads alive."""

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

LEAKY_TESTS = '''
import threading
import time

from PySide6.QtCore import QRunnable, QThreadPool, QTimer
from PySide6.QtWidgets import QApplication, QLabel

app = QApplication.instance() or QApplication([])
kept = []


def test_thread():
    stop = threading.Event()
    kept.append(stop)
    threading.Thread(target=stop.wait, name="left-behind", daemon=True).start()


def test_widget():
    label = QLabel("left open")
    label.show()
    kept.append(label)


def test_timer():
    timer = QTimer(app)
    timer.start(1000)
    kept.append(timer)


def test_pool_job():
    class Sleeper(QRunnable):
        def run(self):
            time.sleep(8)
    pool = QThreadPool()
    pool.start(Sleeper())
    kept.append(pool)


def test_clean():
    label = QLabel("closed")
    label.show()
    label.close()
    label.deleteLater()
'''


def test_leak_guard_names_what_each_test_left_behind(pytester):
    pytester.makeconftest((Path(__file__).parent / "conftest.py").read_text())
    pytester.makepyfile(test_leaky=LEAKY_TESTS)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=5, errors=4)
    result.stdout.fnmatch_lines_random([
        "left alive after the test: thread 'left-behind'",
        "left alive after the test: top-level widget QLabel ''",
        "left alive after the test: active QTimer '' of QApplication",
        "left alive after the test: QThreadPool with 1 running job(s)",
    ])
