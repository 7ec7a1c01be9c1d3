"""The conftest's leak guard fails tests that leave widgets, timers, pool jobs or threads alive."""

import re
from pathlib import Path

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


def test_orphan_timer():
    timer = QTimer()
    timer.setObjectName("orphan")
    timer.start(1000)
    kept.append(timer)


def test_hidden_widget():
    kept.append(QLabel("never shown, never deleted"))


def test_pool_job():
    class Sleeper(QRunnable):
        def run(self):
            time.sleep(2)  # longer than the grace time below
    pool = QThreadPool()
    pool.start(Sleeper())
    kept.append(pool)


def test_finished_pool_job_that_asked_for_its_thread():
    class Asker(QRunnable):
        def run(self):
            threading.current_thread()  # Python registers the Qt thread as a dummy that never ends

    QThreadPool.globalInstance().start(Asker())
    QThreadPool.globalInstance().waitForDone()


def test_clean():
    label = QLabel("closed")
    label.show()
    label.close()
    label.deleteLater()
    QTimer.singleShot(50, label.clear)  # work that winds down within the grace time is no leak
    finishing = QTimer(app)
    finishing.setSingleShot(True)
    finishing.start(100)
    threading.Thread(target=time.sleep, args=(0.1,)).start()
    cycle = [QLabel("kept only by a garbage cycle")]  # as a closed plot keeps its menus
    cycle.append(cycle)
    cycle[0].show()
'''


KEPT_LABEL = ("left alive after the test: top-level widget QLabel ''; "
              "the first is held by list <- dict['kept'] <- module test_leaky")


def test_leak_guard_names_what_each_test_left_behind(pytester):
    conftest = (Path(__file__).parent / "conftest.py").read_text()
    assert "GRACE_S = 5.0" in conftest
    pytester.makeconftest(conftest.replace("GRACE_S = 5.0", "GRACE_S = 1.0"))  # a shorter wait, same logic
    pytester.makepyfile(test_leaky=LEAKY_TESTS)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=8, errors=6)
    lines = result.stdout.lines
    reasons = {match[1]: lines[index + 1] for index, line in enumerate(lines)
               if (match := re.search(r"ERROR at teardown of (\w+)", line))}
    assert reasons == {
        "test_thread": "left alive after the test: thread 'left-behind'",
        "test_widget": KEPT_LABEL,
        "test_timer": "left alive after the test: active QTimer '' of QApplication",
        "test_orphan_timer": "left alive after the test: active QTimer 'orphan' of no parent",
        "test_hidden_widget": KEPT_LABEL,
        "test_pool_job": "left alive after the test: QThreadPool with 1 running job(s)",
    }


def test_settings_without_a_file_live_in_the_private_folder(qapp, private_settings):
    from PySide6.QtCore import QSettings

    for settings in QSettings(), QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, "ringlight", "x"):
        assert Path(settings.fileName()).is_relative_to(private_settings), settings.fileName()
