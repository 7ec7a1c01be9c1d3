"""Noise in the explorer: profile bands, the SNR map view, the scrub bar's SNR strip, the
display-only denoise and the Layers tab's trusted flags, against brute-force ring statistics
(test_noise.brute_ring_se, reference.brute_ring_image) computed here, never by the code under test."""

import json
import math
import threading
import time

import cv2
import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtGui import QKeySequence
from plain_view import plain_settings
from reference import brute_ring_image, random_impulses, write_dataset
from ringlight.app.window import MainWindow
from ringlight.core import open_dataset
from ringlight.core.colour.display import render
from ringlight.core.colour.layer_report import analyse_layers, analysis_document
from ringlight.core.colour.regions import full_region, rectangle_region
from ringlight.core.rings.noise import median_snr, smoothed
from ringlight.widgets.profile_plot import BAND_SE
from test_noise import REC709_Y, brute_ring_se

HEIGHT, WIDTH, SUPPORT = 12, 11, 6.0
TIMEOUT_MS = 120_000
VIRIDIS_TOP, VIRIDIS_BOTTOM = (253, 231, 37), (68, 1, 84)  # matplotlib's viridis at 1 and 0


@pytest.fixture(scope="module")
def impulses():
    return random_impulses(np.random.default_rng(21), HEIGHT, WIDTH, support=SUPPORT, missing=0.05)


@pytest.fixture(scope="module")
def brute(impulses):
    """Brute-force E_r, T_r and their SE for r = 0..4 (dr 1, the window's default request)."""
    radii = np.arange(0.0, 6.0)
    rings = [brute_ring_image(impulses, HEIGHT, WIDTH, r) for r in radii]
    errors = [brute_ring_se(impulses, HEIGHT, WIDTH, r) for r in radii]
    transient = np.array([rings[i] - rings[i + 1] for i in range(5)])
    se = np.array([np.hypot(errors[i][0], errors[i + 1][0]) for i in range(5)])
    se_y = np.array([np.hypot(errors[i][1], errors[i + 1][1]) for i in range(5)])
    with np.errstate(invalid="ignore", divide="ignore"):
        snr = np.abs(transient @ REC709_Y) / se_y
    return {"ring": np.array(rings[:5]), "ring_se": np.array([e[0] for e in errors[:5]]),
            "transient": transient, "transient_se": se, "snr": snr}


@pytest.fixture
def dataset(tmp_path, impulses):
    folder = tmp_path / "dataset"
    write_dataset(folder, HEIGHT, WIDTH, impulses, max_radius=SUPPORT)
    return folder


@pytest.fixture
def window(qtbot, tmp_path):
    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    window.resize(1200, 800)
    window.show()
    qtbot.waitExposed(window)
    yield window
    window.shutdown()


def open_with_noise(qtbot, window, path):
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(path)
    qtbot.waitUntil(lambda: window.noise is not None, timeout=TIMEOUT_MS)


def test_profile_bands_are_e_and_t_plus_minus_two_standard_errors(qtbot, window, dataset, brute):
    open_with_noise(qtbot, window, dataset)
    assert window.stacks.pair.radii.tolist() == [0, 1, 2, 3, 4]
    y, x = 6, 4
    window.pick(y, x)
    ring_bands, transient_bands = window.profile_plot.band_data()
    for values, errors, bands in ((brute["ring"], brute["ring_se"], ring_bands),
                                  (brute["transient"], brute["transient_se"], transient_bands)):
        for channel, (radii, low, high) in enumerate(bands):
            defined = np.isfinite(errors[:, y, x, channel])
            assert radii.tolist() == np.arange(5.0)[defined].tolist()  # r = 0 has one member: no band
            value, error = values[defined, y, x, channel], errors[defined, y, x, channel]
            np.testing.assert_allclose(high, value + BAND_SE * error, rtol=1e-5, atol=1e-7)
            np.testing.assert_allclose(low, value - BAND_SE * error, rtol=1e-5, atol=1e-7)
    assert f"band ±{BAND_SE:g} SE" in window.profile_plot.ring_plot.titleLabel.text
    assert "standard errors" in window.profile_plot.toolTip()


def test_ctrl_5_shows_the_snr_map_with_its_colour_bar(qtbot, window, dataset, brute):
    open_with_noise(qtbot, window, dataset)
    window.set_radius(2.0)
    action = next(a for menu in window.menuBar().actions() if menu.menu() for a in menu.menu().actions()
                  if a.shortcut() == QKeySequence("Ctrl+5"))
    action.trigger()
    assert window.view() == "snr"
    np.testing.assert_allclose(window.noise.snr[2], brute["snr"][2], rtol=2e-4)
    # pyqtgraph's viridis over SNR 0..10, clipped; matplotlib's viridis ends at these colours.
    viridis = pg.colormap.get("viridis")
    assert tuple(viridis.map(1.0, mode="byte")[:3]) == VIRIDIS_TOP
    assert tuple(viridis.map(0.0, mode="byte")[:3]) == VIRIDIS_BOTTOM
    expected = viridis.map(np.clip(brute["snr"][2] / 10, 0, 1).ravel(), mode="byte")[:, :3]
    assert np.abs(window.image_panel.pixels().reshape(-1, 3).astype(int) - expected).max() <= 1
    assert window.image_panel.colour_bar is not None and window.image_panel.colour_bar.values == (0.0, 10.0)
    assert "viridis 0..10 (above: 10)" in window.image_panel.title.toPlainText()
    assert window.describe_pixel(3, 5).startswith(f"y 3  x 5   SNR {brute['snr'][2, 3, 5]:.4g}")
    window.display_controls.set_view("transient")
    assert window.image_panel.colour_bar is None


def median_or_nan(values):
    return np.median(values) if len(values) else np.nan


def test_the_snr_strip_holds_the_median_snr_per_radius_over_the_image_or_region(qtbot, window, dataset, brute):
    open_with_noise(qtbot, window, dataset)
    strip = window.scrub_bar.snr_strip
    expected = [median_or_nan(image[np.isfinite(image)]) for image in brute["snr"]]
    assert np.isnan(expected[0])  # r = 0: one ring member, no SE
    np.testing.assert_allclose(strip.values(), expected, rtol=2e-4)
    assert f"r = 3: median SNR = |Y(T_r)| / SE of T_r over the image: {expected[3]:.3g}" in strip.tooltip_text(3)

    window.analysis_tabs.setCurrentWidget(window.layer_panel)
    panel = window.layer_panel
    panel.region_box.setCurrentIndex(panel.region_box.findData("rectangle"))
    region = rectangle_region((HEIGHT, WIDTH), *window.image_panel.region_geometry()[1])
    expected = [median_or_nan(image[region & np.isfinite(image)]) for image in brute["snr"]]
    np.testing.assert_allclose(strip.values(), expected, rtol=2e-4)
    assert "over the Layers region" in strip.tooltip_text(1)


def test_the_image_wide_median_snr_is_computed_in_the_worker_not_the_gui_thread(qtbot, window, dataset,
                                                                               monkeypatch):
    """On a 1024 x 1024 grid the medians of 21 SNR images take about 0.4 s: the GUI thread must
    not spend them when the noise arrives."""
    import ringlight.app.noise_view as noise_view

    threads = []

    def recorded(snr, region=None):
        threads.append(threading.current_thread() is threading.main_thread())
        return median_snr(snr, region)

    monkeypatch.setattr(noise_view, "median_snr", recorded)
    open_with_noise(qtbot, window, dataset)
    assert threads and not any(threads)  # computed, and only in workers
    expected = median_snr(window.noise.snr)
    np.testing.assert_array_equal(window.scrub_bar.snr_strip.values(), expected)


def test_denoise_is_labelled_and_reaches_exports_only_when_asked(qtbot, window, dataset, tmp_path):
    open_with_noise(qtbot, window, dataset)
    window.set_radius(1.0)
    raw = window.image_panel.pixels().copy()
    plain_grab = window.image_panel.grab().toImage()
    controls = window.display_controls
    controls.sigma_box.setValue(1.5)
    controls.denoise_box.setChecked(True)
    image, levels = window.stacks.pair.transient.images[1], window.current_levels()
    denoised = render(smoothed(image, 1.5), levels, window.display_settings(), "sRGB")
    assert np.array_equal(window.image_panel.shown_pixels(), denoised) and not np.array_equal(denoised, raw)
    label = window.image_panel.display_label.toPlainText()
    assert label == "denoised for display:\nGaussian sigma 1.5 grid steps\nexports raw"

    # Exports: the data pixels and the panel as without the denoise.
    assert np.array_equal(window.image_panel.pixels(), raw)
    assert window.image_panel.grab().toImage() == plain_grab
    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.export_png(tmp_path / "raw.png")
    assert np.array_equal(cv2.cvtColor(cv2.imread(str(tmp_path / "raw.png")), cv2.COLOR_BGR2RGB), raw)

    controls.denoise_exports_box.setChecked(True)  # the explicit option
    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.export_png(tmp_path / "denoised.png")
    assert np.array_equal(cv2.cvtColor(cv2.imread(str(tmp_path / "denoised.png")), cv2.COLOR_BGR2RGB), denoised)
    assert window.image_panel.grab().toImage() != plain_grab
    controls.denoise_box.setChecked(False)
    assert np.array_equal(window.image_panel.shown_pixels(), raw) and not window.image_panel.display_label.isVisible()


def layered_with_noise(folder, sigma, seed=3):
    """A homogeneous surface, I_q(p) = exp(-|p - q| / 2) * colour + sigma * N(0, 1) per channel:
    T_r falls with r while its noise does not, so the SNR crosses 3 at some radius."""
    rng = np.random.default_rng(seed)
    size = 14
    yy, xx = np.mgrid[:size, :size]
    colour = np.array([0.9, 0.6, 0.3])
    impulses = {}
    for qy in range(size):
        for qx in range(size):
            distance = np.hypot(yy - qy, xx - qx)
            image = np.exp(-distance / 2)[..., None] * colour + sigma * rng.standard_normal((size, size, 3))
            image[distance > 7] = 0.0
            impulses[(qy, qx)] = image.astype(np.float32)
    write_dataset(folder, size, size, impulses, max_radius=7.0)
    return impulses


def brute_region_snr(impulses, size, radius, region):
    """|mean Y(T_r)| over the region / sqrt(mean SE(Y)^2 / m), from the brute-force ring spread."""
    transient = (brute_ring_image(impulses, size, size, radius)
                 - brute_ring_image(impulses, size, size, radius + 1)) @ REC709_Y
    inner, outer = brute_ring_se(impulses, size, size, radius)[1], brute_ring_se(impulses, size, size, radius + 1)[1]
    variance = inner ** 2 + outer ** 2
    defined = region & np.isfinite(transient)
    return transient[defined].mean() / np.sqrt(np.nanmean(variance[defined]) / defined.sum())


def test_the_trusted_flag_is_region_snr_of_at_least_3_and_flips_with_the_noise(tmp_path):
    region = rectangle_region((14, 14), 3, 3, 11, 11)
    snr = {}
    for sigma in (0.002, 0.5):
        impulses = layered_with_noise(tmp_path / f"s{sigma}", sigma)
        analysis = analyse_layers(open_dataset(tmp_path / f"s{sigma}", use_cache=False), region, "centre",
                                  radii=[1.0, 4.0])
        document = json.loads(json.dumps(analysis_document(analysis, "dataset")))
        for layer, radius in zip(document["layers"], (1.0, 4.0)):
            expected = brute_region_snr(impulses, 14, radius, region)
            assert layer["snr"] == pytest.approx(expected, rel=1e-4)
            assert layer["trusted"] == (expected >= 3)
            snr[sigma, radius] = expected
        assert "at least 3 standard errors" in document["trust"]
    # Measured: SNR 1586 and 676 at sigma 0.002, 6.4 and 2.1 at sigma 0.5: r = 4 loses its flag.
    assert snr[0.002, 4.0] >= 3 > snr[0.5, 4.0] and min(snr[0.002, 1.0], snr[0.5, 1.0]) >= 3


def test_the_layers_table_shows_pending_then_the_snr_behind_each_flag(qtbot, window, tmp_path, monkeypatch):
    from ringlight.app import noise_view

    impulses = layered_with_noise(tmp_path / "noisy", 0.5)  # measured: SNR 9.4 at r = 1, 2.4 at r = 4
    estimate, release = noise_view.compute_view_noise, threading.Event()

    def held(dataset, pair, progress):  # the estimate waits (cancellable) until released: no race with Esc
        while not release.is_set():
            progress(0.0)
            time.sleep(0.01)
        return estimate(dataset, pair, progress)
    monkeypatch.setattr(noise_view, "compute_view_noise", held)
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(tmp_path / "noisy")
    panel = window.layer_panel
    window.analysis_tabs.setCurrentWidget(panel)
    window.noise_jobs.cancel()  # as Esc would: the flags are then unknown
    for radius in (1.0, 4.0):
        window.set_radius(radius)
        window.layer_tab.toggle_pick(radius)
    assert window.noise is None
    assert panel.table.item(0, 9).text() == "pending" and "estimating the noise" in panel.message_label.text()
    release.set()
    window.display_controls.set_view("ring")  # any change of view asks for the noise again
    qtbot.waitUntil(lambda: window.noise is not None, timeout=TIMEOUT_MS)
    whole = full_region((14, 14))
    for row, radius in enumerate((1.0, 4.0)):
        expected = brute_region_snr(impulses, 14, radius, whole)
        assert panel.table.item(row, 8).text() == f"{expected:.3g}"
        assert panel.table.item(row, 9).text() == ("yes" if expected >= 3 else "no")
        assert "at least 3 standard errors" in panel.table.item(row, 9).toolTip()
    assert [layer.trusted for layer in window.layer_tab.analysis.result.layers] == [True, False]


def readout_numbers(text):
    """[(value, error)] of the readout's RGB, ``0.1912±0.0031`` each."""
    tokens = text.split("RGB ")[1].split(" (")[0].split()
    return [tuple(float(part) for part in token.split("±")) for token in tokens]


def test_the_hover_readout_gives_each_value_with_its_standard_error_and_follows_the_radius(qtbot, window, dataset,
                                                                                          brute):
    """The values to the digit their error allows (the error to two significant digits), against
    brute-force transients and ring-spread errors; scrubbing with the mouse still updates it."""
    open_with_noise(qtbot, window, dataset)
    window.display_controls.set_view("transient")
    y, x = 6, 4
    window.set_radius(1.0)
    window._on_hover(y, x)
    for radius in (1, 2, 3):
        window.set_radius(float(radius))  # the mouse has not moved: the readout follows the image
        text = window.hover_label.text()
        assert text.startswith(f"y {y}  x {x}   RGB ") and text.endswith(" at r+dr") and "(±1 SE)" in text
        for (value, error), truth, truth_error in zip(readout_numbers(text), brute["transient"][radius, y, x],
                                                      brute["transient_se"][radius, y, x]):
            unit = 10.0 ** (math.floor(math.log10(truth_error)) - 1)  # the error's second digit
            assert abs(error - truth_error) <= 0.5 * unit * 1.001 + 1e-4 * truth_error
            assert abs(value - truth) <= 0.5 * unit * 1.001 + 1e-4 * abs(truth)
    window.display_controls.set_view("ring")
    for (value, error), truth, truth_error in zip(readout_numbers(window.hover_label.text()),
                                                  brute["ring"][3, y, x], brute["ring_se"][3, y, x]):
        unit = 10.0 ** (math.floor(math.log10(truth_error)) - 1)
        assert abs(error - truth_error) <= 0.5 * unit * 1.001 + 1e-4 * truth_error
        assert abs(value - truth) <= 0.5 * unit * 1.001 + 1e-4 * abs(truth)
