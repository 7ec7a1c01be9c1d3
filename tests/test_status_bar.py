"""The status bar's temporary message elided before the permanent widgets, its whole text the tooltip."""

import threading

import numpy as np
from PySide6.QtWidgets import QLabel, QMainWindow
from ringlight.widgets.status_bar import ElidingStatusBar

LINE = ("T_r is uniform at every radius (layered?): its structure is in depth, the layer colours "
        "(Analysis > Layers). Try: scrub r, Fit (F)")


def bar_window(qtbot, width: int):
    window = QMainWindow()
    bar = ElidingStatusBar(window)
    window.setStatusBar(bar)
    job = QLabel("Noise of 11 radii: reading the frames")
    bar.addPermanentWidget(job)
    window.resize(width, 120)
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    return window, bar, job


def test_a_long_message_ends_in_an_ellipsis_before_a_running_jobs_label_and_the_tooltip_holds_it_all(qtbot):
    window, bar, job = bar_window(qtbot, 600)
    bar.showMessage(LINE)
    room = bar.message_room()
    shown = bar.shown_message()
    assert shown.endswith("…") and LINE.startswith(shown[:-1].rstrip())
    assert bar.fontMetrics().horizontalAdvance(shown) <= room.width()
    assert room.right() < job.geometry().left() and bar.toolTip() == LINE
    # Nothing is drawn between the message's room and the job's label (Qt's own bar drew the line up
    # to 2 px before the label, its end cut off there).
    image = bar.grab().toImage()
    ratio = image.devicePixelRatio()
    pixels = np.array([[image.pixelColor(int(x * ratio), int(y * ratio)).lightness()
                        for x in range(room.right() + 2, job.geometry().left())]
                       for y in range(bar.height())])
    assert pixels.size and np.ptp(pixels) == 0
    drawn = np.array([[image.pixelColor(int(x * ratio), int(y * ratio)).lightness()
                       for x in range(room.left(), room.right())] for y in range(bar.height())])
    assert np.ptp(drawn) > 100  # the line itself is drawn in the room
    # Once the job's label goes, the room reaches the bar's end and the whole line fits.
    job.hide()
    bar.resize(2000, bar.height())
    assert bar.shown_message() == LINE
    bar.clearMessage()
    assert bar.toolTip() == "" and bar.shown_message() == "" and window.statusBar() is bar


def test_a_running_jobs_indicator_takes_no_more_room_than_it_needs(qtbot):
    """The indicator (label, progress bar, Cancel) in a wide bar showing a message: its width is its
    size hint's, so the message keeps the rest (the bar's expanding progress bar made the
    indicator take a share of the room, a blank stretch after its label's text)."""
    from PySide6.QtCore import QThreadPool
    from ringlight.widgets.job_indicator import JobIndicator
    from ringlight.widgets.jobs import JobSlot

    window = QMainWindow()
    bar = ElidingStatusBar(window)
    window.setStatusBar(bar)
    pool = QThreadPool()
    slot = JobSlot(pool)
    indicator = JobIndicator(slot)
    bar.addPermanentWidget(indicator)
    window.resize(1366, 120)
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    release = threading.Event()
    slot.start("Noise of 11 radii", lambda progress: release.wait(10))  # runs until released
    bar.showMessage("short")
    try:
        qtbot.waitUntil(lambda: indicator.isVisible())
        assert indicator.width() == indicator.sizeHint().width()
        assert bar.message_room().right() >= 1366 - indicator.sizeHint().width() - 40
    finally:
        release.set()
        pool.waitForDone(10000)
