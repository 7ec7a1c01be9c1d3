"""The explorer's scalar views: one channel or luminance through a chosen colour map with its
colour bar, the signed map's bar, the T_r minus ground-truth view, the SNR map's colour map, and
the ring tint letting the data show through. Driven through Qt (offscreen, 1366 x 768).

Expected pixels come from pyqtgraph's own colour maps and colour-science's sRGB encoding applied
here to brute-force stacks (tests/reference.py), never from the code under test.
"""

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPointF
import pytest
from plain_view import plain_settings
from reference import brute_ring_image, random_impulses, write_dataset, write_truth_dataset
from ringlight.core.colourspaces import colour_module
from ringlight.widgets.image_panel import MAX_MEMBER_ALPHA

HEIGHT, WIDTH, SUPPORT = 14, 12, 6.0
TIMEOUT_MS = 120_000
REC709_Y = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def impulses():
    return random_impulses(np.random.default_rng(4), HEIGHT, WIDTH, support=SUPPORT, missing=0.05)


@pytest.fixture(scope="module")
def truth_images():
    rng = np.random.default_rng(9)
    return [rng.uniform(0, 1, (HEIGHT, WIDTH, 3)).astype(np.float32) for _ in range(8)]


@pytest.fixture
def dataset(tmp_path, impulses, truth_images):
    return write_truth_dataset(tmp_path / "dataset", HEIGHT, WIDTH, impulses, truth_images, SUPPORT)


def brute_transient(impulses, radius):
    return brute_ring_image(impulses, HEIGHT, WIDTH, radius) - brute_ring_image(impulses, HEIGHT, WIDTH, radius + 1)


def opened(qtbot, window, path):
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(path)
    window.set_radius(2.0)
    return window


def show(window, key):
    controls = window.display_controls
    controls.shown_box.setCurrentIndex(controls.shown_box.findData(key))


def test_one_channel_through_a_chosen_map_with_its_colour_bar(qtbot, window, dataset, impulses):
    opened(qtbot, window, dataset)
    show(window, "G")
    window.display_controls.set_colormap_name("channel", "viridis")
    assert window.display_controls.map_box.currentText() == "viridis"
    green = brute_transient(impulses, 2.0)[..., 1]
    finite = np.isfinite(green)
    high = np.percentile(green[finite], 99.5)
    assert window.current_levels() == (0.0, pytest.approx(high, rel=1e-5))
    expected = pg.colormap.get("viridis").map(np.clip(np.nan_to_num(green) / high, 0, 1).ravel(), mode="byte")
    shown = window.image_panel.pixels().reshape(-1, 3).astype(int)
    defined = finite.ravel()
    assert np.abs(shown[defined] - expected[defined, :3].astype(int)).max() <= 2  # 256-entry table
    bar = window.image_panel.colour_bar
    assert bar is not None and bar.values == pytest.approx((0.0, high), rel=1e-5)
    assert bar.getAxis("left").labelText == "G"
    show(window, "rgb")
    assert window.image_panel.colour_bar is None and not window.display_controls.map_box.isEnabled()


def test_luminance_in_grey_is_the_srgb_encoding_of_y(qtbot, window, dataset, impulses):
    opened(qtbot, window, dataset)
    show(window, "Y")
    luminance = brute_transient(impulses, 2.0) @ REC709_Y
    finite = np.isfinite(luminance)
    high = np.percentile(luminance[finite], 99.5)
    encoded = colour_module().cctf_encoding(np.clip(np.nan_to_num(luminance) / high, 0, 1), function="sRGB")
    shown = window.image_panel.pixels().astype(int)
    assert np.abs(shown[finite][:, 0] - np.round(encoded[finite] * 255)).max() <= 1
    assert (shown[finite][:, 0] == shown[finite][:, 2]).all()


def test_the_signed_view_has_a_symmetric_colour_bar_and_a_choice_of_diverging_maps(qtbot, window, dataset, impulses):
    opened(qtbot, window, dataset)
    show(window, "signed")
    luminance = brute_transient(impulses, 2.0) @ REC709_Y
    magnitude = np.percentile(np.abs(luminance[np.isfinite(luminance)]), 99.5)
    assert window.image_panel.colour_bar.values == pytest.approx((-magnitude, magnitude), rel=1e-5)
    window.display_controls.set_colormap_name("signed", "CET-D1A")
    table = pg.colormap.get("CET-D1A").getLookupTable(0.0, 1.0, 256, alpha=False)
    position = np.clip(np.nan_to_num(luminance) / magnitude, -1, 1)
    expected = table[np.clip(((position + 1) / 2) * 255 + 0.5, 0, 255).astype(int)]
    finite = np.isfinite(luminance)
    assert np.abs(window.image_panel.pixels()[finite].astype(int) - expected[finite]).max() <= 1


def test_the_difference_view_subtracts_the_least_squares_multiple_of_the_truth(qtbot, window, dataset, impulses,
                                                                               truth_images):
    opened(qtbot, window, dataset)
    window.display_controls.set_view("difference")
    transient, truth = brute_transient(impulses, 2.0), truth_images[2]  # T_2 bounds [2, 3): bin 2
    both = np.isfinite(transient)
    scale = np.linalg.lstsq(truth[both][:, None].astype(np.float64), transient[both], rcond=None)[0][0]
    np.testing.assert_allclose(window._shown_image[both], transient[both] - scale * truth[both], atol=1e-5)
    assert f"a = {scale:.4g}" in window.image_panel.title.toPlainText()
    assert window.image_panel.colour_bar is not None  # always drawn signed
    assert window.display_controls.map_kind() == "signed"
    assert not window.display_controls.shown_box.isEnabled()  # a difference is always drawn signed


def test_the_difference_view_says_when_there_is_no_truth(qtbot, window, tmp_path, impulses):
    folder = tmp_path / "plain"
    write_dataset(folder, HEIGHT, WIDTH, impulses, max_radius=SUPPORT)
    opened(qtbot, window, folder)
    window.display_controls.set_view("difference")
    assert "no ground truth" in window.image_panel.title.toPlainText()


def test_the_ring_tint_lets_most_of_the_image_through(qtbot, window, dataset):
    opened(qtbot, window, dataset)
    window.pick(7, 6)
    overlay = window.image_panel.ring_overlay()
    members = overlay[..., 3] > 0
    assert members.any() and overlay[..., 3].max() <= MAX_MEMBER_ALPHA
    # Composited over white, the blue channel (the yellow tint has none) keeps >= 62 % of the image.
    assert 255 * (1 - overlay[members, 3] / 255).min() >= 0.62 * 255


def test_the_line_profile_dock_follows_the_shown_image_and_exports_csv(qtbot, window, dataset, impulses, tmp_path):
    opened(qtbot, window, dataset)
    action = window.line_profile_dock.toggleViewAction()
    assert action.shortcut().toString() == "Ctrl+Shift+L"
    action.trigger()
    assert window.line_profile_dock.isVisible() and window.line_profile.roi.scene() is not None
    # The default line runs along the middle row's pixel centres from 20 % to 80 % of the width.
    (y0, x0), (y1, x1) = window.line_profile.line()
    assert y0 == y1 == HEIGHT // 2 + 0.5
    columns = np.arange(int(x0), int(x1) + 1)
    distances, values = window.line_profile.profile()
    np.testing.assert_allclose(distances, columns - columns[0])
    np.testing.assert_allclose(values, brute_transient(impulses, 2.0)[HEIGHT // 2, columns], rtol=1e-5, atol=1e-7)
    window.set_radius(3.0)  # scrubbing feeds the new image
    np.testing.assert_allclose(window.line_profile.profile()[1], brute_transient(impulses, 3.0)[HEIGHT // 2, columns],
                               rtol=1e-5, atol=1e-7)
    path = tmp_path / "line.csv"
    window._save_path = lambda *args: path
    window.choose_line_profile_export()
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 1:], window.line_profile.profile()[1], rtol=1e-8)
    action.trigger()
    assert window.line_profile.roi.scene() is None


def test_colour_map_choices_survive_a_restart(qtbot, window, tmp_path):
    from ringlight.app.window import MainWindow

    window.display_controls.set_colormap_name("channel", "inferno")
    window.display_controls.set_colormap_name("snr", "cividis")
    window.save_settings()
    again = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(again)
    try:
        assert again.display_controls.colormap_names() == {"channel": "inferno", "signed": "RdBu", "snr": "cividis"}
    finally:
        again.shutdown()


def test_the_ring_tint_is_drawn_on_its_members_and_nowhere_else(qtbot, window, dataset):
    """The tint is an image over the ring's bounding box only: on screen, a member pixel is the
    alpha blend of the data and the tint, the picked pixel inside the box (not a member at r = 3)
    is the data alone."""
    from ringlight.widgets.image_panel import MEMBER_RGB

    opened(qtbot, window, dataset)
    window.set_radius(3.0)
    window.pick(7, 6)
    window.image_panel.marker.setData([], [])  # the cross would cover the picked pixel
    overlay, data = window.image_panel.ring_overlay(), window.image_panel.pixels().astype(float)
    grabbed = window.image_panel.grab().toImage()
    ratio = window.image_panel.devicePixelRatioF()

    def on_screen(y, x):
        point = window.image_panel.mapFromScene(window.image_panel.view.mapViewToScene(QPointF(x + 0.5, y + 0.5)))
        colour = grabbed.pixelColor(round(point.x() * ratio), round(point.y() * ratio))
        return np.array([colour.red(), colour.green(), colour.blue()], float)

    members = np.argwhere((overlay[..., 3] > 0) & np.all(overlay[..., :3] == MEMBER_RGB, axis=-1))
    assert len(members) > 8 and overlay[7, 6, 3] == 0
    for y, x in members[::3]:
        alpha = overlay[y, x, 3] / 255
        expected = data[y, x] * (1 - alpha) + np.array(MEMBER_RGB) * alpha
        assert np.abs(on_screen(y, x) - expected).max() <= 3
    assert np.abs(on_screen(7, 6) - data[7, 6]).max() <= 3
