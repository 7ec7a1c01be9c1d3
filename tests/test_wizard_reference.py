"""The capture wizard's "Calibrate on a reference" on a finished scan (the homogeneous dataset of
test_optics_window, absolute: the model's own response, so its scale is 1): the file it writes
reads back with the scale calibrate() gives, it never replaces a file ringlight did not write,
and bad numbers get one line."""

import json

import numpy as np
import pytest

pytest.importorskip("PySide6")
from PySide6.QtCore import QThreadPool  # noqa: E402
from optics_helpers import TEST_PHOTONS  # noqa: E402
from ringlight.app.capture_tab import CaptureTab  # noqa: E402
from ringlight.core import open_dataset  # noqa: E402
from ringlight.core.optics import calibrate, read_calibration  # noqa: E402
from ringlight.widgets.capture_wizard import FINISH, CaptureWizard  # noqa: E402
from ringlight.widgets.reference_calibration import parse_coefficients  # noqa: E402
from test_optics_window import MUA, MUSP, homogeneous  # noqa: E402, F401 (a fixture)

WAIT_MS = 120_000


@pytest.fixture
def tab(qtbot):
    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    pool = QThreadPool()
    pool.setMaxThreadCount(1)  # as the window's capture pool
    tab = CaptureTab(wizard, pool, wizard)
    tab.calibration_photons = TEST_PHOTONS
    tab.errors = []
    tab.error.connect(lambda title, message: tab.errors.append(message))
    wizard.go_to(FINISH)
    yield tab
    tab.shutdown()
    pool.waitForDone()


def fill(box, scan, out, mua="0.2", musp="5, 5, 5"):
    box.set_scan(str(scan))
    box.out_edit.setText(str(out))
    box.mua_edit.setText(mua)
    box.musp_edit.setText(musp)
    box.description_edit.setText("the model's own half-space")


def test_the_calibration_written_reads_back_with_calibrates_scale(qtbot, tab, homogeneous, tmp_path):
    box = tab.wizard.reference_box
    out = tmp_path / "rig-calibration.json"
    fill(box, homogeneous, out)
    with qtbot.waitSignal(tab.calibration_jobs.finished, timeout=WAIT_MS):
        box.calibrate_button.click()
    written = read_calibration(out)
    expected = calibrate(open_dataset(homogeneous), MUA, MUSP, photons=TEST_PHOTONS)
    np.testing.assert_allclose(written.scale, expected.scale, rtol=1e-12)
    np.testing.assert_allclose(written.scale_se, expected.scale_se, rtol=1e-12)
    # The dataset is absolute (the model's response with 2 % noise): its scale is 1.
    np.testing.assert_allclose(written.scale, 1.0, atol=0.03)
    assert written.reference_mua == (MUA,) * 3 and written.reference_musp == (MUSP,) * 3
    assert written.units == "per_mm" and written.n == 1.4 and written.description == "the model's own half-space"
    assert str(out) in box.status_label.text() and not tab.errors
    # Again into the same file: a calibration ringlight wrote is replaced.
    with qtbot.waitSignal(tab.calibration_jobs.finished, timeout=WAIT_MS):
        box.calibrate_button.click()
    assert read_calibration(out).scale == written.scale


def test_a_file_ringlight_did_not_write_is_never_replaced(qtbot, tab, homogeneous, tmp_path):
    out = tmp_path / "notes.json"
    out.write_text(json.dumps({"my": "notes"}))
    fill(tab.wizard.reference_box, homogeneous, out)
    with qtbot.waitSignal(tab.calibration_jobs.failed, timeout=WAIT_MS):
        tab.wizard.reference_box.calibrate_button.click()
    assert json.loads(out.read_text()) == {"my": "notes"}
    assert len(tab.errors) == 1 and "\n" not in tab.errors[0] and "notes.json" in tab.errors[0]


def test_bad_coefficients_get_one_line_and_no_work(qtbot, tab, homogeneous, tmp_path):
    box = tab.wizard.reference_box
    fill(box, homogeneous, tmp_path / "c.json", mua="0.2, 0.3")
    box.calibrate_button.click()
    assert not tab.calibration_jobs.busy
    assert box.status_label.text() == "mu_a: give one positive number or three (R, G, B), got '0.2, 0.3'"
    assert parse_coefficients("0.1 0.2,0.3", "mu_a") == (0.1, 0.2, 0.3)
    for text in ("", "-1", "nan", "a"):
        with pytest.raises(ValueError):
            parse_coefficients(text, "mu_a")
