"""The capture wizard's live view, dark frame and colour steps on the simulated rig looking at a
ColorChecker, and a scan from the wizard whose dataset records the fitted matrix."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("PySide6")
from PySide6.QtCore import QThreadPool  # noqa: E402
from ringlight.app.capture_tab import CaptureTab  # noqa: E402
from ringlight.core import open_dataset  # noqa: E402
from ringlight.core.capture.simulated_presets import preset_rig  # noqa: E402
from ringlight.core.capture.simulated_rig import CAMERA_RGB_TO_XYZ  # noqa: E402
from ringlight.widgets.capture_wizard import CaptureWizard  # noqa: E402
from test_cameras_calibration import camera_pixel  # noqa: E402

OPTIONS = "scene=colorchecker size=28x42"
WAIT_MS = 60000


@pytest.fixture
def tab(qtbot):
    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    pool = QThreadPool()
    pool.setMaxThreadCount(1)  # as the window's capture pool
    tab = CaptureTab(wizard, pool, wizard)  # as in the window: the tab dies with its parent
    errors = []
    tab.error.connect(lambda title, message: errors.append(message))
    wizard.options_edit.setText(OPTIONS)
    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        wizard.open_button.click()
    yield tab
    tab.shutdown()
    pool.waitForDone()
    tab.close_devices()
    assert not errors


def test_live_view_streams_frames_with_saturation_and_histogram_until_stopped(qtbot, tab):
    wizard = tab.wizard
    frames = []
    tab.live_frame.connect(frames.append)
    wizard.live_page.exposure_box.setValue(2.0)  # 2 ms: the bright patches saturate, dark ones and gaps do not
    tab.projector.show_white()
    with qtbot.waitSignal(tab.live_frame, timeout=WAIT_MS):
        wizard.live_page.start_button.click()
    qtbot.waitUntil(lambda: len(frames) >= 2, timeout=WAIT_MS)
    assert wizard.live_page.stop_button.isEnabled() and not wizard.live_page.start_button.isEnabled()
    with qtbot.waitSignal(tab.live_jobs.idle, timeout=WAIT_MS):
        wizard.live_page.stop_button.click()
    assert wizard.live_page.start_button.isEnabled()
    live = frames[-1]
    rows, cols = tab.camera.frame_shape[:2]
    assert live.histogram.sum() == rows * cols * 3
    # The red overlay marks exactly the saturated pixels.
    red = np.all(live.pixels == (255, 0, 64), axis=-1)
    assert red.mean() == pytest.approx(live.saturated_fraction) and 0 < live.saturated_fraction < 1
    assert np.array_equal(wizard.live_page.view.pixels(), live.pixels)
    assert f"{live.saturated_fraction:.2%} of pixels saturated" in wizard.live_page.status.text()


def test_dark_step_prints_the_cameras_read_noise(qtbot, tab):
    page = tab.wizard.dark_page
    page.frames_box.setValue(8)
    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        page.capture_button.click()
    read_noise = preset_rig(scene="colorchecker", size="28x42").sensor.read_noise
    expected = math.sqrt(read_noise**2 + 1 / 12)  # Gaussian read noise plus rounding to integers
    assert tab.dark.noise == pytest.approx(expected, rel=0.03)
    assert f"noise {tab.dark.noise:.2f} counts rms" in page.result.text()


def test_colour_step_fits_the_simulated_cameras_matrix_and_the_scan_records_it(qtbot, tab, tmp_path):
    wizard, page = tab.wizard, tab.wizard.colour_page
    rig = preset_rig(scene="colorchecker", size="28x42")
    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        page.capture_button.click()
    assert not page.fit_button.isEnabled() and "patch 1 dark skin" in page.instructions.text()
    for row, col in ((0, 0), (0, 5), (3, 0), (3, 5)):  # clicks on the corner patches' centres
        y, x = camera_pixel(rig.sampling, (row + 0.5) * 28 / 4, (col + 0.5) * 42 / 6)
        page.view.pixel_picked.emit(int(round(y)), int(round(x)))
    assert page.fit_button.isEnabled()
    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        page.fit_button.click()
    # Frames are counts per second = gain x camera RGB: the fit is the camera's matrix / gain.
    np.testing.assert_allclose(tab.colour_fit.matrix * rig.sensor.gain, CAMERA_RGB_TO_XYZ, atol=0.01)
    assert "residual" in page.result.text()

    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        wizard.correspondence_button.click()
    wizard.set_roi((8, 8, 20, 20))
    wizard.radius_box.setValue(1.0)
    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        wizard.probe_button.click()
    assert "per capture beyond its exposure" in wizard.plan_label.text()
    wizard.multiplex_box.setCurrentIndex(1)  # Hadamard code of 7
    wizard.out_edit.setText(str(tmp_path / "chart"))
    with qtbot.waitSignal(tab.jobs.finished, timeout=WAIT_MS):
        wizard.scan_button.click()
    manifest = json.loads((tmp_path / "chart/dataset.json").read_text())
    assert manifest["colorspace"] == tab.colour_fit.colorspace()
    assert "Projector check" in manifest["notes"] and "radiance +0.00% to +0.00% of the first" in manifest["notes"]
    assert json.loads((tmp_path / "chart/.scan/plan.json").read_text())["multiplex"] == 7
    dataset = open_dataset(tmp_path / "chart", use_cache=False)
    assert dataset.colorspace.startswith("ringlight custom matrix")
