"""The explorer's Optics tab on a homogeneous dataset written as frames (the maps' model response
with 2 % noise per response value, pitch 0.1 mm): the maps it computes in its worker are
optical_maps' own, the hover readout gives their numbers, the Profiles tab draws model_profile
at the picked pixel, cancel stops the work, and a bad calibration file gives one line."""

import dataclasses
import re
import threading

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtCore import QRunnable
from optics_helpers import TEST_PHOTONS, model_kernel
from plain_view import plain_settings
from reference import write_dataset
from ringlight.app.optics_view import OpticsRequest, describe_optics, region_fit_text, region_text
from ringlight.app.window import MainWindow
from ringlight.core import Cancelled, open_dataset
from ringlight.core.dataset.exr import read_exr_channels
from ringlight.core.optics import model_profile, optical_maps, radial, region_optics

MUA, MUSP = 0.2, 5.0  # per mm: 0.02 and 0.5 per grid step of 0.1 mm
SIZE, MAX_RADIUS = 16, 5
TIMEOUT_MS = 120_000


@pytest.fixture(scope="module")
def homogeneous(tmp_path_factory):
    """The dataset's folder: every point lit, frames of points 11 apart."""
    run = radial.run_radial(1.4, 0.0, TEST_PHOTONS, seed=0)  # the seed the window's table uses
    kernel = model_kernel(run, MUSP * 0.1, MUA * 0.1, MAX_RADIUS)
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    impulses = {}
    for y in range(SIZE):
        for x in range(SIZE):
            image = np.zeros((SIZE, SIZE, 3), np.float32)
            y0, y1 = max(0, y - MAX_RADIUS), min(SIZE, y + MAX_RADIUS + 1)
            x0, x1 = max(0, x - MAX_RADIUS), min(SIZE, x + MAX_RADIUS + 1)
            window = kernel[y0 - y + MAX_RADIUS:y1 - y + MAX_RADIUS, x0 - x + MAX_RADIUS:x1 - x + MAX_RADIUS]
            image[y0:y1, x0:x1] = window * (1 + 0.02 * rng.standard_normal(window.shape))
            image[np.hypot(yy - y, xx - x) > MAX_RADIUS] = 0.0
            impulses[(y, x)] = image
    folder = tmp_path_factory.mktemp("optics") / "homogeneous"
    write_dataset(folder, SIZE, SIZE, impulses, max_radius=MAX_RADIUS, multiplex=True,
                  extra={"grid": {"height": SIZE, "width": SIZE, "pitch_mm": 0.1}, "sample": {"n": 1.4}})
    return folder


@pytest.fixture(scope="module")
def direct(homogeneous):
    """The maps computed straight from core, never through the window."""
    return optical_maps(open_dataset(homogeneous), photons=TEST_PHOTONS)


@pytest.fixture
def window(qtbot, tmp_path, homogeneous):
    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    window.resize(1300, 850)
    window.show()
    qtbot.waitExposed(window)
    window.optics_photons = TEST_PHOTONS
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(homogeneous)
    qtbot.waitUntil(lambda: not window.stack_jobs.busy, timeout=TIMEOUT_MS)
    yield window
    window.shutdown()


def compute(qtbot, window):
    window.analysis_tabs.setCurrentWidget(window.optics_panel)
    window.optics_panel.compute_button.click()
    qtbot.waitUntil(lambda: window.optics is not None, timeout=TIMEOUT_MS)


def shown(text: str, name: str) -> tuple[float, float]:
    match = re.search(re.escape(name) + r" ([0-9.]+)±([0-9.]+) /mm", text)
    assert match, text
    return float(match.group(1)), float(match.group(2))


def test_hover_shows_the_maps_optical_maps_gives(qtbot, window, direct):
    compute(qtbot, window)
    for key in ("mua", "musp", "mua_se", "musp_se", "determined"):
        np.testing.assert_array_equal(getattr(window.optics, key), getattr(direct, key))
    assert window.optics.units == "per_mm"
    y, x = 8, 7  # whole rings (7.5 > max_radius from every edge is not needed: 5 suffices)
    assert direct.complete[y, x]
    window.optics_panel.channel_box.setCurrentIndex(1)
    window.optics_panel.image_panel.pixel_hovered.emit(y, x)
    text = window.optics_panel.hover_label.text()
    assert text.startswith(f"y {y}  x {x}  G:")
    for key, name, truth in (("mua", "mu_a", MUA), ("musp", "mu_s'", MUSP)):
        value, error = shown(text, name)
        expected, expected_error = float(getattr(direct, key)[y, x, 1]), float(getattr(direct, f"{key}_se")[y, x, 1])
        # with_error gives the error to two significant digits, the value to the same decimal.
        assert error == pytest.approx(expected_error, rel=0.05)
        assert abs(value - expected) <= 0.051 * expected_error
        assert abs(value - truth) < 4 * error  # and the truth the dataset was made of lies within
    assert "not determined" not in text
    # The colour bar names the quantity and its units.
    window.optics_panel.quantity_box.setCurrentIndex(1)
    assert window.optics_panel.image_panel.colour_bar.getAxis("left").labelText == "mu_s' (/mm)"


def test_not_determined_values_say_so(direct):
    # The core's flag alone decides: mu_a of pixel (3, 4) in R flagged, nothing else.
    flags = direct.mua_determined.copy()
    flags[3, 4, 0] = False
    maps = dataclasses.replace(direct, mua_determined=flags)
    text = describe_optics(maps, 3, 4, 0)
    assert re.search(r"mu_a [0-9.]+±[0-9.]+ /mm \(not determined\)", text)
    assert text.count("not determined") == 1
    assert "not determined" not in describe_optics(maps, 3, 4, 1)


def test_profiles_tab_draws_model_profile_at_the_picked_pixel(qtbot, window, direct):
    compute(qtbot, window)
    y, x = 6, 9
    window.pick(y, x)
    radii, model = window.profile_plot.model_data()
    np.testing.assert_array_equal(radii, direct.radii)
    for channel in range(3):
        expected = model_profile(float(direct.mua[y, x, channel]), float(direct.musp[y, x, channel]), direct.radii,
                                 n=1.4, g=0.0, pitch_mm=0.1, photons=TEST_PHOTONS)
        np.testing.assert_allclose(model[:, channel], expected, rtol=1e-12)
    # The model lies on the measured profile: within 3 standard deviations of the 2 % noise,
    # 6 % at ring 0 (one member), 3 % from ring 1 on (8 members or more).
    measured_radii, ring, _ = window.profile_plot.curve_data()
    common = np.isin(measured_radii, radii)
    fitted = model[np.isin(radii, measured_radii)]
    np.testing.assert_allclose(fitted[0], ring[common][0], rtol=0.06)
    np.testing.assert_allclose(fitted[1:], ring[common][1:], rtol=0.03)
    # A pick before any maps draws no model.
    window._forget_optics()
    window.pick(y, x)
    assert len(window.profile_plot.model_data()[0]) == 0


def test_region_statistics_are_mean_and_its_standard_error(direct):
    # Over determined pixels whose rings are whole (the cut rings' fits are biased).
    region = np.zeros(direct.mua.shape[:2], bool)
    region[3:11, 3:11] = True
    used = region & direct.musp_determined[..., 2] & direct.complete
    cut = int((region & direct.musp_determined[..., 2] & ~direct.complete).sum())
    assert used.sum() >= 30 and cut > 0  # both kinds lie in this region
    text = region_text(direct, "musp", 2, region, "Layers region")
    values = direct.musp[..., 2][used].astype(np.float64)
    mean, se = shown(text, "mu_s' B mean")
    assert f"{used.sum()} of 64 px ({cut} more with rings cut by the edge left out)" in text
    assert se == pytest.approx(values.std(ddof=1) / np.sqrt(len(values)), rel=0.05)
    assert abs(mean - values.mean()) <= 0.051 * se
    # Beside it, what one pixel's data allow: the median of those pixels' own standard errors.
    pixel_se = float(re.search(r"each pixel's SE ([0-9.e-]+) \(median\)", text).group(1))
    assert pixel_se == pytest.approx(np.median(direct.musp_se[..., 2][used]), rel=0.05)  # two digits
    assert abs(mean - MUSP) < 0.02 * MUSP  # the truth the dataset was made of


def test_the_map_takes_its_colours_from_whole_rings_and_dims_the_cut_ones(qtbot, window, direct):
    compute(qtbot, window)
    values = direct.mua[..., 0]
    determined = direct.mua_determined[..., 0] & np.isfinite(values)
    trusted = determined & direct.complete
    assert trusted.sum() >= 30 and (determined & ~direct.complete).sum() >= 30
    low, high = np.percentile(values[trusted], (1.0, 99.0))
    assert window.optics_panel.levels == pytest.approx((low, high), rel=1e-12)
    # Each pixel's colour is viridis at its place in those levels, a cut or undetermined one at 0.45 of it.
    viridis = pg.colormap.get("viridis")
    expected = viridis.map(np.clip((values - low) / (high - low), 0.0, 1.0).ravel(), mode="float")[:, :3] * 255
    expected = expected.reshape(values.shape + (3,))
    expected[~trusted] *= 0.45
    shown_pixels = window.optics_panel.image_panel.pixels().astype(np.float64)
    finite = np.isfinite(values)
    assert np.abs(shown_pixels[finite] - expected[finite]).max() <= 3.0  # the 256-entry table's rounding
    assert "rings cut (edge, unlit points)" in window.optics_panel.image_panel.title.textItem.toPlainText()


def test_the_maps_are_exported_as_the_command_writes_them(qtbot, window, direct, homogeneous, tmp_path, monkeypatch):
    # Before any maps: one line saying what to do, and the panel's button is off.
    assert not window.optics_panel.export_button.isEnabled()
    window.choose_optics_export()
    assert window.last_error == "Compute the maps first (Analysis > Optics, Compute maps)."
    compute(qtbot, window)
    assert window.optics_panel.export_button.isEnabled()
    path = tmp_path / "maps.exr"
    monkeypatch.setattr("ringlight.app.export_actions.QFileDialog.getSaveFileName", lambda *args: (str(path), ""))
    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.optics_panel.export_button.click()
    names = [f"{p}.{c}{s}" for p in ("mua", "musp") for c in "RGB" for s in ("", "_se")]
    names += [f"determined.{c}" for c in "RGB"] + ["complete"]
    written = read_exr_channels(path, tuple(names))
    for index, name in enumerate(names):
        key, _, channel = name.partition(".")
        if key == "complete":
            expected = direct.complete.astype(np.float32)
        else:
            suffix = "_se" if channel.endswith("_se") else ""
            plane = getattr(direct, key + suffix)[..., "RGB".index(channel[0])]
            expected = plane.astype(np.float32)
        np.testing.assert_array_equal(written[..., index], expected, err_msg=name)
    # Computing again (other n, say) drops the maps at once: neither shown, hovered nor exported.
    window.compute_optics()
    assert window.optics is None and not window.optics_panel.export_button.isEnabled()
    window.cancel_optics()
    compute(qtbot, window)
    # Never over a file of the dataset the maps came from, which the save dialog cannot know.
    manifest = homogeneous / "dataset.json"
    before = manifest.read_bytes()
    with qtbot.waitSignal(window.export_jobs.failed, timeout=TIMEOUT_MS):
        window.export_optics(manifest)
    assert window.last_error.startswith(f"{manifest}: is a file of the dataset") and manifest.read_bytes() == before


def test_a_region_is_fitted_as_the_command_fits_it_and_forgotten_when_the_region_changes(qtbot, window, homogeneous):
    panel = window.optics_panel
    with qtbot.waitSignal(window.optics_region_jobs.finished, timeout=TIMEOUT_MS):
        panel.fit_region_button.click()
    dataset = window.loaded.dataset
    whole = region_optics(dataset, None, photons=TEST_PHOTONS)
    text = panel.region_fit_label.text()
    assert text == region_fit_text(whole, "whole grid")
    assert text.startswith(f"whole grid, fit of its mean E(r) over {SIZE * SIZE} lit points (n 1.4, g 0): mu_a ")
    # Its numbers are the core's fit, each to the digits its standard error allows, and the truth lies within.
    for name, values, errors, truth in (("mu_a", whole.mua, whole.mua_se, MUA), ("mu_s'", whole.musp, whole.musp_se,
                                                                                MUSP)):
        shown_values = re.search(re.escape(name) + r" ([0-9.±/ ]+?)(?:,| /mm)", text).group(1).split(" / ")
        for shown_text, value, error in zip(shown_values, values, errors):
            number, shown_error = (float(part) for part in shown_text.split("±"))
            assert shown_error == pytest.approx(error, rel=0.05)
            assert abs(number - value) <= 0.051 * error
            assert abs(value - truth) < 4 * error
    # A rectangle drawn on the Layers tab: the old fit is gone, and the next fit is the rectangle's.
    layers = window.layer_panel
    layers.region_box.setCurrentIndex(layers.region_box.findData("rectangle"))
    assert panel.region_fit_label.text() == ""
    y0, x0, y1, x1 = window.image_panel.region_geometry()[1]
    mask = np.zeros((SIZE, SIZE), bool)
    mask[y0:y1, x0:x1] = True
    np.testing.assert_array_equal(window.layer_tab.region, mask)
    with qtbot.waitSignal(window.optics_region_jobs.finished, timeout=TIMEOUT_MS):
        panel.fit_region_button.click()
    assert panel.region_fit_label.text() == region_fit_text(region_optics(dataset, mask, photons=TEST_PHOTONS),
                                                            "Layers region")
    assert f"over {mask.sum()} lit points" in panel.region_fit_label.text()


def test_cancel_stops_the_maps(qtbot, window, homogeneous):
    # The pool's one thread held by a job of the test's own: the maps' job waits, queued, so the
    # cancel always comes before its result however fast the machine (a cached table is).
    release = threading.Event()
    blocker = QRunnable.create(lambda: release.wait(60))
    window.pool.start(blocker)
    window.optics_panel.compute_button.click()
    assert window.optics_jobs.busy and window.optics_panel.cancel_button.isEnabled()
    window.optics_panel.cancel_button.click()
    assert not window.optics_jobs.busy and not window.optics_panel.cancel_button.isEnabled()
    release.set()
    window.pool.waitForDone()
    qtbot.wait(50)  # any queued signal of the cancelled job delivered
    assert window.optics is None  # the cancelled job's result never arrives
    assert window.optics_panel.image_panel.title.toPlainText().startswith("Cancelled")
    # The fit itself asks the request's stop event: a stopped request raises Cancelled.
    stop = threading.Event()
    stop.set()
    with pytest.raises(Cancelled):
        OpticsRequest(open_dataset(homogeneous), None, TEST_PHOTONS, stop).run(lambda fraction: None)


def test_cancel_stops_a_region_fit_and_the_maps_job_does_not_hide_it(qtbot, window):
    release = threading.Event()
    blocker = QRunnable.create(lambda: release.wait(60))
    window.pool.start(blocker)  # both jobs wait, queued, behind it (as in test_cancel_stops_the_maps)
    panel = window.optics_panel
    panel.fit_region_button.click()
    panel.fit_region_button.click()  # the second supersedes the first, and says so too
    panel.compute_button.click()
    panel.compute_button.click()
    assert window.optics_region_jobs.busy and window.optics_jobs.busy  # neither cancelled the other
    assert panel.region_fit_label.text() == "whole grid: fitting its mean E(r) ..."
    assert panel.image_panel.title.toPlainText() == "Fitting mu_a and mu_s' of every pixel ..."
    panel.cancel_button.click()
    assert not window.optics_region_jobs.busy and not window.optics_jobs.busy
    assert not panel.cancel_button.isEnabled() and panel.region_fit_label.text() == ""
    release.set()
    window.pool.waitForDone()
    qtbot.wait(50)
    assert panel.region_fit_label.text() == "" and window.optics is None  # no result arrives after the cancel


@pytest.mark.parametrize("content", ["{not json", '{"format": "ringlight-impulse", "version": 1}'])
def test_a_bad_calibration_file_gives_one_line_naming_it(qtbot, window, tmp_path, content):
    path = tmp_path / "rig-calibration.json"
    path.write_text(content)
    assert not window.load_calibration(path)
    assert "\n" not in window.last_error and "rig-calibration.json" in window.last_error
    assert window.optics_calibration is None


def test_the_typed_index_is_the_one_fitted_and_a_bad_one_gives_one_line(qtbot, window):
    window.optics_panel.n_edit.setText("1.4x")
    window.optics_panel.compute_button.click()
    assert not window.optics_jobs.busy and window.last_error == "n must be a number, got '1.4x'"
    window.optics_panel.n_edit.setText("1.33")
    compute(qtbot, window)
    assert window.optics.n == 1.33 and window.optics.g == 0.0  # g: the manifest states none, so 0
