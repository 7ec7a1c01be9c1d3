"""The pylon camera plugin against pylon's own camera emulation (PYLON_CAMEMU), through the real
SDK: enumeration by serial, pixel formats, exposure, black level, timeouts, and a whole scan."""

import importlib.util
import math

import cv2
import numpy as np
import pytest
from ringlight.app.main import main
from ringlight.core import open_dataset
from ringlight.core.capture.hardware import HardwareError
from ringlight.core.capture.pylon_camera import PylonCamera, list_cameras, make_pylon_camera
from ringlight.core.capture.simulated_presets import preset_rig

# Not importorskip: pypylon is imported by the plugin only, which silences its import warnings.
pytestmark = pytest.mark.skipif(importlib.util.find_spec("pypylon") is None, reason="pypylon is not installed")


@pytest.fixture(autouse=True)
def emulated_cameras(monkeypatch):
    """Two emulated cameras, 0815-0000 and 0815-0001 (pylon reads the variable at enumeration)."""
    monkeypatch.setenv("PYLON_CAMEMU", "2")


@pytest.fixture
def opened():
    cameras = []

    def open_camera(camera):
        camera.open()
        cameras.append(camera)
        return camera
    yield open_camera
    for camera in cameras:
        camera.close()


def test_emulated_cameras_are_enumerated_and_opened_by_serial(opened):
    assert [camera["serial"] for camera in list_cameras()] == ["0815-0000", "0815-0001"]
    camera = opened(PylonCamera("0815-0001", "Mono16"))
    properties = camera.properties()
    assert (properties["serial"], properties["pixel format"], properties["gain"]) == ("0815-0001", "Mono16", "0 dB")
    assert camera.saturation_level == 2**16 - 1
    with pytest.raises(HardwareError, match="no camera with serial '42'; found 0815-0000, 0815-0001"):
        PylonCamera("42").open()


def test_fed_frames_arrive_unchanged_with_the_rigs_black_level_and_range(opened):
    camera = opened(make_pylon_camera(feed="simulated", size="8x8", photons="100"))
    rig = preset_rig(size="8x8", photons="100")
    assert (camera.black_level, camera.saturation_level) == (rig.sensor.black_level, 4095.0)
    assert camera.exposure_range == rig.sensor.exposure_range  # inside the emulator's 1 us .. 10 s
    pattern = np.zeros(rig.size, np.float32)
    pattern[3, 4] = 1.0
    rig.projector.show(pattern)
    frame = camera.capture(0.02)
    # The rig's frames are deterministic in pattern, exposure and repeat: the same capture, done directly.
    rig.projector.show(pattern)
    np.testing.assert_array_equal(frame, np.round(rig.capture(0.02).mean(axis=-1)))
    assert frame.max() > 1000
    with pytest.raises(HardwareError, match="exposure 5 s outside"):
        camera.capture(5.0)


@pytest.mark.parametrize("pattern", ["RG", "GR", "GB", "BG"])
def test_bayer_frames_are_demosaiced_keeping_every_measured_sample(opened, tmp_path, pattern):
    rows, cols = np.mgrid[:24, :32]
    known = np.stack([100 * rows + 7 * cols, 50 * cols + 9 * rows, 3000 + 40 * rows + 20 * cols], -1).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "known.tiff"), known[..., ::-1])  # OpenCV writes BGR
    camera = opened(PylonCamera("0815-0000", f"Bayer{pattern}16"))
    for name, value in (("TestImageSelector", "Off"), ("ImageFileMode", "On"),
                        ("ImageFilename", str(tmp_path / "known.tiff")), ("Width", 32), ("Height", 24)):
        camera._set_feature(name, value)
    frame = camera.capture(0.001)
    assert frame.shape == (24, 32, 3)
    # The emulator mosaics the file: pattern "RG" has R at even rows and columns, etc.
    rows_of_sites = {"RG": ("RG", "GB"), "GR": ("GR", "BG"), "GB": ("GB", "RG"), "BG": ("BG", "GR")}[pattern]
    site = np.array([["RGB".index(colour) for colour in row] for row in rows_of_sites])[rows % 2, cols % 2]
    measured = np.take_along_axis(frame, site[..., None], -1)[..., 0]
    # Inside the one-pixel border (which OpenCV fills from its neighbours) every sample is kept.
    np.testing.assert_array_equal(measured[1:-1, 1:-1], np.take_along_axis(known, site[..., None], -1)[1:-1, 1:-1, 0])
    # The image is linear in rows and columns, so bilinear interpolation is exact inside it.
    np.testing.assert_allclose(frame[2:-2, 2:-2], known[2:-2, 2:-2], atol=1.0)


def test_exposure_in_seconds_reaches_the_camera_in_microseconds(opened):
    camera = opened(PylonCamera("0815-0000", "Mono16"))
    # The emulator's ExposureTime runs from 1 us to 10 s (its node's own limits, in microseconds).
    assert camera.exposure_range == (pytest.approx(1e-6), pytest.approx(10.0))
    for seconds in (0.0005, 0.25):
        camera.capture(seconds)
        assert camera._feature("ExposureTime") == pytest.approx(seconds * 1e6)
    assert camera._feature("ExposureAuto") == "Off" and camera._feature("GainAuto") == "Off"


def test_a_camera_that_sends_no_frame_times_out_with_a_hardware_error(opened):
    camera = opened(PylonCamera("0815-0000", "Mono12", frame_timeout="0.2"))

    waits = []

    class TriggerLost:
        """The real camera, whose software trigger never arrives: the SDK's own wait times out."""

        def __getattr__(self, name):
            return getattr(real, name)

        def ExecuteSoftwareTrigger(self):
            pass

        def RetrieveResult(self, timeout_ms, handling):
            waits.append(timeout_ms)
            return real.RetrieveResult(timeout_ms, handling)

    real, camera.camera = camera.camera, TriggerLost()
    try:
        with pytest.raises(HardwareError, match=r"pylon camera 0815-0000: no frame within 0.201 s \(frame timeout\)"):
            camera.capture(0.001)
    finally:
        camera.camera = real
    assert waits == [201]  # one wait, bounded by the SDK: 1 ms exposure + 0.2 s frame timeout
    assert camera.capture(0.001).shape == camera.frame_shape  # grabbing restarts after a timeout


def test_a_disconnected_camera_is_a_hardware_error(opened):
    camera = opened(PylonCamera("0815-0000", "Mono12"))
    try:
        camera._node("DeviceModelName").SetValue("x")  # read-only: a real SDK exception to replay
    except Exception as error:  # noqa: BLE001 - the SDK's own exception type, whatever it is
        sdk_error = error

    class Unplugged:
        """The real camera whose cable was pulled: the SDK raises and reports the removal."""

        def __getattr__(self, name):
            return getattr(real, name)

        def RetrieveResult(self, *args):
            raise sdk_error

        def IsCameraDeviceRemoved(self):
            return True

    real, camera.camera = camera.camera, Unplugged()
    try:
        with pytest.raises(HardwareError, match="pylon camera 0815-0000: disconnected"):
            camera.capture(0.001)
    finally:
        camera.camera = real


def test_capture_command_scans_through_the_emulator_into_a_dataset_that_opens(tmp_path, capsys):
    out = tmp_path / "pylon-scan"
    assert main(["capture", "--camera", "pylon", "--projector", "simulated", "--option", "size=10x10",
                 "--option", "photons=200", "--camera-option", "feed=simulated", "--max-radius", "3",
                 "--out", str(out)]) == 0
    assert "49 frames instead of 100" in capsys.readouterr().out
    dataset = open_dataset(out, use_cache=False)
    assert dataset.grid_shape == (10, 10) and len(dataset.manifest.frames) == 49
    assert dataset.lit.all() and np.isfinite(dataset.responses).all()
    for recorded in ("model Emulation", "serial 0815-0000", "pixel format Mono12", "gain 0 dB", "black level 64"):
        assert recorded in dataset.manifest.notes


def test_wizard_live_dark_and_colour_steps_run_through_the_emulator(qtbot):
    from PySide6.QtCore import QThreadPool
    from ringlight.app.capture_tab import CaptureTab
    from ringlight.core.capture.simulated_rig import CAMERA_RGB_TO_XYZ
    from ringlight.widgets.capture_wizard import CaptureWizard
    from test_cameras_calibration import camera_pixel

    wizard = CaptureWizard()
    qtbot.addWidget(wizard)
    pool = QThreadPool()
    pool.setMaxThreadCount(1)
    tab = CaptureTab(wizard, pool, wizard)
    errors = []
    tab.error.connect(lambda title, message: errors.append(message))
    wizard.camera_box.setCurrentText("pylon")
    wizard.options_edit.setText("scene=colorchecker size=28x42")
    wizard.camera_options_edit.setText("feed=simulated pixel_format=BayerRG12")
    try:
        with qtbot.waitSignal(tab.jobs.finished, timeout=30000):
            wizard.open_button.click()
        assert tab.camera.properties()["serial"] == "0815-0000" and tab.camera.frame_shape[2] == 3
        frames = []
        tab.live_frame.connect(frames.append)
        with qtbot.waitSignal(tab.live_frame, timeout=30000):
            wizard.live_page.start_button.click()
        with qtbot.waitSignal(tab.live_jobs.idle, timeout=30000):
            wizard.live_page.stop_button.click()
        assert frames[0].histogram.sum() == np.prod(tab.camera.frame_shape)
        wizard.dark_page.frames_box.setValue(8)
        with qtbot.waitSignal(tab.jobs.finished, timeout=30000):
            wizard.dark_page.capture_button.click()
        # Demosaicing averages neighbouring samples: the dark noise lies between the read noise of
        # one sample (2 counts, plus rounding) and that of the mean of four (1). Measured: 1.56.
        assert 1.0 < tab.dark.noise < math.sqrt(4 + 1 / 12)
        rig = preset_rig(scene="colorchecker", size="28x42")
        with qtbot.waitSignal(tab.jobs.finished, timeout=30000):
            wizard.colour_page.capture_button.click()
        for row, col in ((0, 0), (0, 5), (3, 0), (3, 5)):
            y, x = camera_pixel(rig.sampling, (row + 0.5) * 28 / 4, (col + 0.5) * 42 / 6)
            wizard.colour_page.view.pixel_picked.emit(int(round(y)), int(round(x)))
        with qtbot.waitSignal(tab.jobs.finished, timeout=30000):
            wizard.colour_page.fit_button.click()
        # Measured: largest difference 0.009 (the Bayer mosaic samples each colour at a quarter of the pixels).
        np.testing.assert_allclose(tab.colour_fit.matrix * rig.sensor.gain, CAMERA_RGB_TO_XYZ, atol=0.02)
    finally:
        tab.shutdown()
        pool.waitForDone()
        tab.close_devices()
    assert not errors
