"""The capture wizard's own controls: Back/Next, scan buttons by state, one percentage."""

import pytest

pytest.importorskip("PySide6")
from ringlight.widgets.capture_wizard import STEPS, CaptureWizard  # noqa: E402
from ringlight.widgets.job_indicator import JobIndicator  # noqa: E402
from ringlight.widgets.jobs import JobSlot  # noqa: E402


def test_back_and_next_walk_every_step(qtbot):
    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    assert wizard.steps.currentRow() == 0 and not wizard.back_button.isEnabled()
    for step in range(1, len(STEPS)):
        wizard.next_button.click()
        assert wizard.steps.currentRow() == step == wizard.pages.currentIndex()
    assert not wizard.next_button.isEnabled()
    wizard.back_button.click()
    assert wizard.steps.currentRow() == len(STEPS) - 2


@pytest.mark.parametrize("state, start, pause, resume", [
    ("idle", True, False, True), ("running", False, True, False), ("paused", False, False, True)])
def test_scan_buttons_follow_the_scan_state(qtbot, state, start, pause, resume):
    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    wizard.set_scan_state(state)
    assert (wizard.scan_button.isEnabled(), wizard.pause_button.isEnabled(), wizard.resume_button.isEnabled()) == (
        start, pause, resume)


def test_progress_bar_and_label_give_the_same_percentage(qtbot):
    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    fraction = 0.7866  # the bar's own text would truncate to 78 %, the label rounds to 79 %
    wizard.set_scan_progress(fraction, f"{fraction:.0%} done")
    assert wizard.scan_bar.text() == "79%" and wizard.scan_label.text().startswith("79%")


def test_job_indicator_is_busy_until_progress_arrives(qtbot):
    from PySide6.QtCore import QThreadPool

    pool = QThreadPool()
    slot = JobSlot(pool)
    indicator = JobIndicator(slot)
    qtbot.addWidget(indicator)
    slot.started.emit("Opening devices")
    assert (indicator.bar.minimum(), indicator.bar.maximum()) == (0, 0)  # Qt's busy indicator
    slot.progress.emit(0.25)
    assert (indicator.bar.maximum(), indicator.bar.value()) == (1000, 250)


def test_colour_page_takes_four_corner_clicks_in_order_and_clears_them(qtbot):
    import numpy as np

    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    page = wizard.colour_page
    page.view.pixel_picked.emit(3, 4)  # no chart yet: ignored
    assert page.corners == [] and not page.fit_button.isEnabled()
    page.show_chart(np.ones((40, 60, 3), np.float32))
    fitted = []
    page.fit_requested.connect(fitted.append)
    for y, x in ((5, 6), (5, 50), (30, 6), (30, 50)):
        assert not page.fit_button.isEnabled()
        page.view.pixel_picked.emit(y, x)
    page.view.pixel_picked.emit(20, 20)  # one click too many: ignored
    assert page.fit_button.isEnabled() and "Four patches picked" in page.instructions.text()
    page.fit_button.click()
    assert fitted == [[(5, 6), (5, 50), (30, 6), (30, 50)]]
    assert page.points.data["x"].tolist() == [6.5, 50.5, 6.5, 50.5]  # drawn at the pixels' centres
    page.clear_button.click()
    assert page.corners == [] and "patch 1 dark skin" in page.instructions.text()


def test_multiplexing_choice_gives_the_code_order(qtbot):
    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    orders = []
    for index in range(wizard.multiplex_box.count()):
        wizard.multiplex_box.setCurrentIndex(index)
        orders.append(wizard.multiplex_order())
    assert orders == [0, 7, 15, 31]


def test_opening_a_camera_and_projector_of_different_rigs_is_an_error_and_opens_neither(qtbot):
    """The wizard's "Camera options" field is the camera's alone: ``seed=1`` there made the camera a
    rig of its own, which never saw the projector's patterns. Opening says so and holds no device."""
    from PySide6.QtCore import QThreadPool
    from ringlight.app.capture_tab import CaptureTab

    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    pool = QThreadPool()
    tab = CaptureTab(wizard, pool, wizard)
    errors = []
    tab.error.connect(lambda title, message: errors.append(message))
    wizard.options_edit.setText("size=4x4 photons=10")
    wizard.camera_options_edit.setText("seed=1")
    with qtbot.waitSignal(tab.jobs.failed, timeout=60000):
        wizard.open_button.click()
    pool.waitForDone()
    assert errors == ["the camera and the projector were given different simulated rigs (seed: camera 1, projector 0): "
                      "give scene, size, photons and seed once, as options for both devices"]
    assert tab.camera is None and tab.projector is None
    tab.shutdown()
