"""The explorer window, driven through Qt (pytest-qt, offscreen) on independently written datasets.

Expected values come from brute force (tests/reference.py) and from colour-science's sRGB
encoding applied here, never from the code under test.
"""

import csv
import json
import math

import cv2
import numpy as np
import pytest
from PySide6.QtCore import QMimeData, QPoint, QPointF, QSettings, Qt, QUrl
from PySide6.QtGui import QDropEvent
from plain_view import plain_settings
from reference import (
    brute_ring_image,
    random_impulses,
    supersampled_annulus_weight,
    write_dataset,
    write_truth_dataset,
)
from ringlight.app.window import MainWindow
from ringlight.core import read_stack
from ringlight.core.colour.display import UNDEFINED_RGB
from ringlight.core.colourspaces import colour_module
from ringlight.core.rings.stack_request import StackRequest
from ringlight.widgets.image_panel import member_alpha

HEIGHT, WIDTH, SUPPORT = 14, 12, 6.0
LOAD_TIMEOUT_MS = 120_000


@pytest.fixture(scope="module")
def impulses():
    return random_impulses(np.random.default_rng(4), HEIGHT, WIDTH, support=SUPPORT, missing=0.05)


@pytest.fixture
def truth_images():
    rng = np.random.default_rng(9)
    return [rng.uniform(0, 1, (HEIGHT, WIDTH, 3)).astype(np.float32) for _ in range(8)]


@pytest.fixture
def dataset(tmp_path, impulses, truth_images):
    """A one-point-per-frame dataset with max_radius and 8 ground-truth bins of width 1."""
    return write_truth_dataset(tmp_path / "dataset", HEIGHT, WIDTH, impulses, truth_images, SUPPORT)


@pytest.fixture
def window(qtbot, tmp_path):
    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    window.resize(1200, 800)
    window.show()
    qtbot.waitExposed(window)
    window.activateWindow()  # shortcuts need the active window under a real X server
    yield window
    window.shutdown()


def open_and_wait(qtbot, window, path):
    with qtbot.waitSignal(window.dataset_loaded, timeout=LOAD_TIMEOUT_MS):
        window.open_dataset(path)


def compute_and_wait(qtbot, window, request):
    window.stack_controls.set_request(request)
    with qtbot.waitSignal(window.stacks_ready, timeout=LOAD_TIMEOUT_MS):
        window.request_stacks(request)


def click_pixel(qtbot, panel, y, x):
    scene_point = panel.view.mapViewToScene(QPointF(x + 0.5, y + 0.5))
    qtbot.mouseClick(panel.viewport(), Qt.MouseButton.LeftButton, pos=panel.mapFromScene(scene_point))


def srgb_pixels(linear, low, high):
    """Reference display: colour-science's sRGB encoding of (v - low) / (high - low), 8 bit."""
    scaled = np.clip((np.nan_to_num(linear) - low) / (high - low), 0, 1)
    pixels = np.round(colour_module().cctf_encoding(scaled, function="sRGB") * 255).astype(np.uint8)
    pixels[~np.isfinite(linear).all(-1)] = UNDEFINED_RGB
    return pixels


def brute_transient(impulses, radius, dr, thickness=1.0):
    return (brute_ring_image(impulses, HEIGHT, WIDTH, radius, thickness)
            - brute_ring_image(impulses, HEIGHT, WIDTH, radius + dr, thickness))


def test_opening_shows_the_dataset_and_its_first_transient(qtbot, window, dataset, impulses):
    open_and_wait(qtbot, window, dataset)
    assert window.windowTitle() == "dataset - ringlight"
    status = window.dataset_label.toolTip()
    assert f"grid {WIDTH}x{HEIGHT}" in status and f"{len(impulses)} frames" in status
    assert f"{HEIGHT * WIDTH - len(impulses)} missing" in status and "max_radius 6" in status
    radii = window.stacks.pair.radii
    assert radii[0] == 0 and radii[-1] == 4.0  # r + dr + w/2 = 5.5 <= 6 < 6.5
    assert window.truth_panel.isVisible()
    expected = brute_transient(impulses, 0.0, 1.0)
    shown = window.image_panel.pixels()
    high = np.percentile(expected[np.isfinite(expected)], 99.5)
    assert np.abs(shown.astype(int) - srgb_pixels(expected, 0.0, high)).max() <= 1


@pytest.mark.parametrize("antialias", [False, True])
def test_clicking_a_pixel_draws_the_ring_members_and_its_profiles(qtbot, window, dataset, impulses, antialias):
    open_and_wait(qtbot, window, dataset)
    compute_and_wait(qtbot, window, StackRequest(0.0, 3.0, 0.5, dr=0.5, thickness=1.5, antialias=antialias))
    window.set_radius(2.5)
    y, x = 3, 9
    click_pixel(qtbot, window.image_panel, y, x)
    assert window.picked == (y, x)

    # Ring members by the definition (weights: supersampled pixel coverage for anti-aliasing).
    weight = supersampled_annulus_weight(2.5, 1.5, samples=128) if antialias else None
    expected = {}
    for qy in range(HEIGHT):
        for qx in range(WIDTH):
            distance = math.hypot(qy - y, qx - x)
            w = weight(qy - y, qx - x) if antialias else float(1.75 <= distance < 3.25)
            if w > 0:
                expected[(qy, qx)] = w
    overlay = window.image_panel.ring_overlay()
    drawn = {tuple(position) for position in np.argwhere(overlay[..., 3] > 0)}
    if antialias:  # supersampling misses slivers thinner than 1/128 of a pixel
        assert {p for p, w in expected.items() if w > 0.01} <= drawn <= set(expected) | _slivers(y, x, 2.5, 1.5)
    else:
        assert drawn == set(expected)
    for position, w in expected.items():
        if position in drawn and w > 0.01:
            assert abs(int(overlay[position][3]) - int(member_alpha(np.array([w]))[0])) <= 2

    radii, ring, transient = window.profile_plot.curve_data()
    assert radii.tolist() == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    for index, radius in enumerate(radii):
        w_inner = supersampled_annulus_weight(radius, 1.5, 128) if antialias else None
        w_outer = supersampled_annulus_weight(radius + 0.5, 1.5, 128) if antialias else None
        inner = brute_ring_image(impulses, HEIGHT, WIDTH, radius, 1.5, w_inner)[y, x]
        outer = brute_ring_image(impulses, HEIGHT, WIDTH, radius + 0.5, 1.5, w_outer)[y, x]
        tolerance = 2e-3 if antialias else 1e-5
        np.testing.assert_allclose(ring[index], inner, rtol=tolerance, atol=1e-6)
        np.testing.assert_allclose(transient[index], inner - outer, rtol=tolerance, atol=tolerance * 0.1)
    assert window.profile_plot.radius_lines[0].value() == 2.5


def _slivers(y, x, radius, thickness):
    """Pixels touching the annulus at all (a superset of every member)."""
    outer = radius + thickness / 2 + 0.75
    inner = max(radius - thickness / 2 - 0.75, 0)
    return {(qy, qx) for qy in range(HEIGHT) for qx in range(WIDTH)
            if inner <= math.hypot(qy - y, qx - x) <= outer}


def test_dragging_across_the_image_moves_the_picked_pixel(qtbot, window, dataset):
    open_and_wait(qtbot, window, dataset)
    panel = window.image_panel
    start = panel.mapFromScene(panel.view.mapViewToScene(QPointF(2.5, 2.5)))
    end = panel.mapFromScene(panel.view.mapViewToScene(QPointF(7.5, 5.5)))
    qtbot.mousePress(panel.viewport(), Qt.MouseButton.LeftButton, pos=start)
    for step in range(1, 11):
        qtbot.mouseMove(panel.viewport(), pos=start + (end - start) * (step / 10))
    qtbot.mouseRelease(panel.viewport(), Qt.MouseButton.LeftButton, pos=end)
    assert window.picked == (5, 7)


@pytest.mark.parametrize("mode", ["per-image", "global", "manual", "log", "diverging"])
def test_each_slider_step_shows_the_stack_slice_under_the_chosen_normalisation(qtbot, window, dataset, impulses, mode):
    open_and_wait(qtbot, window, dataset)
    controls = window.display_controls
    if mode == "diverging":
        controls.shown_box.setCurrentIndex(controls.shown_box.findData("signed"))
    else:
        controls.normalisation_box.setCurrentIndex(controls.normalisation_box.findData(mode))
    if mode == "manual":
        controls.low_edit.setText("-0.01")
        controls.high_edit.setText("0.05")
        controls.low_edit.editingFinished.emit()
    expected_stack = np.stack([brute_transient(impulses, r, 1.0) for r in window.stacks.pair.radii])
    finite = expected_stack[np.isfinite(expected_stack)]
    for index in (1, 2, 3):
        qtbot.keyClick(window, Qt.Key.Key_BracketRight)
        assert window.radius_index() == index
        expected = expected_stack[index]
        values = expected[np.isfinite(expected)]
        shown = window.image_panel.pixels().astype(int)
        undefined = ~np.isfinite(expected).all(-1)
        assert (shown[undefined] == UNDEFINED_RGB).all()
        if mode == "per-image":
            reference = srgb_pixels(expected, 0.0, np.percentile(values, 99.5))
        elif mode == "global":
            reference = srgb_pixels(expected, 0.0, np.percentile(finite, 99.5))
        elif mode == "manual":
            reference = srgb_pixels(expected, -0.01, 0.05)
            assert window.current_levels() == (-0.01, 0.05)  # levels stay where the user put them
        elif mode == "log":
            high = np.percentile(values, 99.5)
            low = high / 1000
            scaled = np.log10(np.maximum(np.nan_to_num(expected), low) / low) / 3.0
            reference = np.round(np.clip(scaled, 0, 1) * 255).astype(np.uint8)
        else:  # diverging: sign of luminance decides red (> 0) or blue (< 0)
            luminance = np.nan_to_num(expected) @ colour_module().RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ[1]
            positive, negative = (luminance > 1e-4) & ~undefined, (luminance < -1e-4) & ~undefined
            assert negative.any() and positive.any()  # transients of this dataset have both signs
            assert (shown[positive, 0] > shown[positive, 2]).all()
            assert (shown[negative, 2] > shown[negative, 0]).all()
            continue
        assert np.abs(shown[~undefined] - reference[~undefined].astype(int)).max() <= 1


def test_hover_reports_the_value_and_ring_point_counts(qtbot, window, dataset, impulses):
    """The value to 4 significant digits until the noise is estimated, then to the digit its
    standard error allows (``test_noise_window`` checks the errors)."""
    open_and_wait(qtbot, window, dataset)
    window.set_radius(2.0)
    y, x = 7, 5
    text = window.describe_pixel(y, x)
    expected = brute_transient(impulses, 2.0, 1.0)[y, x]
    for token, truth in zip(text.split("RGB ")[1].split(" (")[0].split("   ")[0].split(), expected, strict=True):
        value, _, error = token.partition("±")
        tolerance = 0.06 * float(error) if error else 5e-4 * abs(truth)
        assert abs(float(value) - truth) <= tolerance + 1e-9, (token, truth)
    inner = sum(1 for q in impulses if 1.5 <= math.hypot(q[0] - y, q[1] - x) < 2.5)
    outer = sum(1 for q in impulses if 2.5 <= math.hypot(q[0] - y, q[1] - x) < 3.5)
    assert f"ring points: {inner} at r, {outer} at r+dr" in text


def test_ground_truth_is_the_nearest_bin_with_its_correlation(qtbot, window, dataset, impulses, truth_images):
    open_and_wait(qtbot, window, dataset)
    window.set_radius(3.0)
    truth = truth_images[3]  # T_3 with dr 1 bounds path length to [3, 4): bin 3
    transient = brute_transient(impulses, 3.0, 1.0)
    both = np.isfinite(transient)
    expected = np.corrcoef(transient[both], truth[both])[0, 1]
    assert window.truth_correlation == pytest.approx(expected, abs=1e-6)
    assert "path length [3, 4)" in window.truth_panel.title.toPlainText()
    high = np.percentile(truth, 99.5)
    assert np.abs(window.truth_panel.pixels().astype(int) - srgb_pixels(truth, 0.0, high)).max() <= 1


def test_a_bad_dataset_shows_the_error_and_keeps_the_open_one(qtbot, window, dataset, tmp_path):
    open_and_wait(qtbot, window, dataset)
    shown = window.image_panel.pixels().copy()
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "dataset.json").write_text('{"format": "ringlight-impulse"')
    with qtbot.waitSignal(window.error_shown, timeout=LOAD_TIMEOUT_MS) as error:
        window.open_dataset(broken)
    assert str(broken / "dataset.json") in error.args[0]
    assert window.loaded.dataset.path == dataset
    assert np.array_equal(window.image_panel.pixels(), shown)
    # A corrupt frame: the message names the file.
    corrupt = tmp_path / "corrupt"
    write_dataset(corrupt, 3, 3, random_impulses(np.random.default_rng(1), 3, 3, 2.0), max_radius=2.0)
    (corrupt / "frames/00004.exr").write_bytes(b"not an exr")
    with qtbot.waitSignal(window.error_shown, timeout=LOAD_TIMEOUT_MS) as error:
        window.open_dataset(corrupt)
    assert "00004.exr" in error.args[0]
    assert window.loaded.dataset.path == dataset


def test_recomputing_keeps_the_old_stack_until_the_new_one_is_ready_or_cancelled(qtbot, window, dataset):
    open_and_wait(qtbot, window, dataset)
    old = window.stacks
    window.request_stacks(StackRequest(1.0, 3.0, 0.25, dr=0.25))
    assert window.stacks is old  # still shown while the worker runs
    window.stack_jobs.cancel()
    qtbot.wait(50)
    assert window.stacks is old and not window.stack_jobs.busy
    compute_and_wait(qtbot, window, StackRequest(1.0, 3.0, 0.25, dr=0.25))
    assert window.stacks.pair.radii.tolist() == [1 + 0.25 * i for i in range(9)]
    assert window.scrub_bar.slider.maximum() == 8


def test_a_request_beyond_max_radius_is_refused_with_a_message(qtbot, window, dataset):
    open_and_wait(qtbot, window, dataset)
    old = window.stacks
    with qtbot.waitSignal(window.error_shown, timeout=LOAD_TIMEOUT_MS) as error:
        window.request_stacks(StackRequest(0.0, 8.0, 1.0))
    assert "beyond the dataset's max_radius 6" in error.args[0] and "largest stop is 4" in error.args[0]
    assert window.stacks is old


def test_exports_write_files_that_read_back_equal(qtbot, window, dataset, tmp_path):
    open_and_wait(qtbot, window, dataset)
    window.pick(4, 4)
    window.set_radius(1.0)
    done = window.export_jobs.finished
    with qtbot.waitSignal(done, timeout=LOAD_TIMEOUT_MS):
        window.export_stack(tmp_path / "stack")
    manifest, images = read_stack(tmp_path / "stack")
    stack = window.stacks.pair.transient
    assert manifest["kind"] == "transient" and manifest["radii"] == stack.radii.tolist()
    assert np.array_equal(images, stack.images, equal_nan=True)

    with qtbot.waitSignal(done, timeout=LOAD_TIMEOUT_MS):
        window.export_png(tmp_path / "view.png")
    png = cv2.cvtColor(cv2.imread(str(tmp_path / "view.png")), cv2.COLOR_BGR2RGB)
    assert np.array_equal(png, window.image_panel.pixels())

    with qtbot.waitSignal(done, timeout=LOAD_TIMEOUT_MS):
        window.export_csv(tmp_path / "profile.csv")
    rows = list(csv.reader((tmp_path / "profile.csv").read_text().splitlines()))
    assert rows[1][:4] == ["radius", "E_R", "E_G", "E_B"]
    table = np.array([[float(value) for value in row] for row in rows[2:]])
    assert np.array_equal(table[:, 0], window.profile.radii)
    assert np.array_equal(table[:, 1:4], window.profile.ring, equal_nan=True)
    assert np.array_equal(table[:, 9:12], window.profile.transient, equal_nan=True)

    with qtbot.waitSignal(done, timeout=LOAD_TIMEOUT_MS):
        window.export_movie(tmp_path / "scrub.mp4")
    capture = cv2.VideoCapture(str(tmp_path / "scrub.mp4"))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    assert len(frames) == len(stack.radii)
    scale = -(-512 // WIDTH)
    assert frames[0].shape == (HEIGHT * scale, WIDTH * scale, 3)
    assert not list(tmp_path.glob(".*partial*"))  # atomic writes leave no temporary files


@pytest.mark.parametrize("export", ["png", "png without an extension", "shown", "csv", "movie", "stack"])
def test_an_export_on_a_full_disk_says_why_in_one_line_and_publishes_nothing(qtbot, window, dataset, tmp_path,
                                                                               export):
    """Issue 40, cases 2 and 3: "Exported" over a 0-byte PNG and a 16 KB MP4 without a frame; an
    internal-error dialog for a PNG named without an extension and for CSV and stack exports on a
    full disk. The disk is full (a file-size limit of 0 bytes) while the export's worker writes."""
    from test_fuzz_writers import disk_full_at

    open_and_wait(qtbot, window, dataset)
    window.pick(4, 4)
    name = {"png": "view.png", "png without an extension": "view", "shown": "shown.png", "csv": "profile.csv",
            "movie": "scrub.mp4", "stack": "stack"}[export]
    path = tmp_path / "out" / name
    path.parent.mkdir()
    start = {"png": window.export_png, "png without an extension": window.export_png, "shown": window.export_shown,
             "csv": window.export_csv, "movie": window.export_movie, "stack": window.export_stack}[export]
    with disk_full_at(0), qtbot.waitSignal(window.error_shown, timeout=LOAD_TIMEOUT_MS) as error:
        start(path)
    message = error.args[0]
    assert "internal error" not in message and "Traceback" not in message, message
    assert str(path) in message and len(message.splitlines()) <= 2, message
    assert list(path.parent.iterdir()) == []
    assert not window.statusBar().currentMessage().startswith("Exported")


def test_layout_settings_and_recent_files_persist(qtbot, dataset, tmp_path):
    settings = QSettings(str(tmp_path / "persist.ini"), QSettings.Format.IniFormat)
    first = MainWindow(settings)
    qtbot.addWidget(first)
    open_and_wait(qtbot, first, dataset)
    first.display_controls.set_view("ring")
    first.display_controls.exposure_slider.setValue(-15)
    first.display_controls.profile_log_box.setChecked(True)
    first.close()
    second = MainWindow(settings)
    qtbot.addWidget(second)
    assert second.view() == "ring"
    assert second.display_settings().exposure_stops == -1.5
    assert second.profile_plot.log_y
    assert second.recent_files() == [str(dataset)]
    assert [action.text() for action in second.recent_menu.actions()] == [f"&1 {dataset}"]
    second.shutdown()


def test_dropping_a_manifest_opens_its_dataset(qtbot, window, dataset):
    mime = QMimeData()
    mime.setUrls([QUrl.fromLocalFile(str(dataset / "dataset.json"))])
    event = QDropEvent(QPointF(10, 10), Qt.DropAction.CopyAction, mime, Qt.MouseButton.LeftButton,
                       Qt.KeyboardModifier.NoModifier)
    with qtbot.waitSignal(window.dataset_loaded, timeout=LOAD_TIMEOUT_MS):
        window.dropEvent(event)
    assert window.loaded.dataset.path == dataset


def test_clicking_a_profile_sets_the_radius(qtbot, window, dataset):
    open_and_wait(qtbot, window, dataset)
    window.profile_dock.show()
    plot = window.profile_plot
    plot.transient_plot.vb.setXRange(0, 4, padding=0)
    qtbot.wait(10)
    scene_point = plot.transient_plot.vb.mapViewToScene(QPointF(2.9, 0.0))
    position = plot.mapFromScene(scene_point)
    qtbot.mouseClick(plot.viewport(), Qt.MouseButton.LeftButton, pos=QPoint(position.x(), position.y()))
    assert window.scrub_bar.radius() == 3.0


def test_screenshot_option_renders_the_window_offscreen_and_exits(dataset, tmp_path, capsys):
    from ringlight.app.main import main

    out = tmp_path / "shot.png"
    assert main([str(dataset), "--screenshot", str(out), "--radius", "2", "--pick", "3,4"]) == 0
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 400 and image.shape[1] > 800
    assert image.std() > 10  # a drawn window, not a blank canvas
    capsys.readouterr()
    assert main([str(dataset), "--screenshot", str(out)]) == 2  # an existing file is never replaced
    assert "exists" in capsys.readouterr().err
    assert main([str(dataset), "--screenshot", str(out), "--overwrite", "--pick", "99,4"]) == 2
    assert "--pick 99,4 is outside the 14x12 grid" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(dataset), "--pick", "3,4"])  # --pick without --screenshot
    # From a user review: --screenshot "" opened the interactive window and waited for good,
    # --radius beyond the stack or NaN wrote a PNG at some other radius, --pick a,b printed
    # int()'s message.
    assert main([str(dataset), "--screenshot", str(out), "--overwrite", "--radius", "40"]) == 2
    assert "--radius 40 is outside the stack shown (radii 0.." in capsys.readouterr().err
    for options, message in ((["--screenshot", ""], "--screenshot needs a file name"),
                             (["--screenshot", str(out), "--radius", "nan"], "--radius must be a finite number"),
                             (["--screenshot", str(out), "--pick", "a,b"], "must be two whole numbers Y,X")):
        with pytest.raises(SystemExit) as stopped:
            main([str(dataset), *options])
        assert stopped.value.code == 2 and message in capsys.readouterr().err


def test_play_advances_at_the_frame_rate_and_stops_at_the_end_without_loop(qtbot):
    from ringlight.widgets.scrub_bar import ScrubBar

    bar = ScrubBar()
    qtbot.addWidget(bar)
    bar.set_radii(np.arange(4.0))
    bar.set_fps(60)
    bar.loop_box.setChecked(False)
    seen = []
    bar.index_changed.connect(seen.append)
    bar.toggle_play()
    assert bar.timer.interval() == 17
    qtbot.waitUntil(lambda: not bar.play_button.isChecked(), timeout=5000)
    assert seen == [1, 2, 3] and bar.index() == 3
    bar.loop_box.setChecked(True)
    bar.toggle_play()  # from the end it restarts at 0 and then wraps around
    qtbot.waitUntil(lambda: len(seen) >= 9, timeout=5000)
    bar.toggle_play()
    assert seen[3:9] == [0, 1, 2, 3, 0, 1]


def test_cancelling_an_open_keeps_the_current_dataset(qtbot, window, dataset, tmp_path, impulses):
    open_and_wait(qtbot, window, dataset)
    other = tmp_path / "other"
    write_dataset(other, HEIGHT, WIDTH, impulses, max_radius=SUPPORT)
    with qtbot.waitSignal(window.load_jobs.cancelled, timeout=LOAD_TIMEOUT_MS):
        window.open_dataset(other)
        window.cancel_all()
    window.pool.waitForDone()
    qtbot.wait(20)
    assert window.loaded.dataset.path == dataset and not window.load_jobs.busy
    assert window.statusBar().currentMessage() == f"Opening cancelled; {dataset.name} stays open"


def test_layers_tab_recovers_the_known_layers_from_picked_radii(qtbot, window, tmp_path):
    from ringlight.core.colour.chroma import recover_layers, srgb_swatch, trajectory
    from ringlight.core.colour.regions import rectangle_region
    from test_layers import LAYER_UNIT, synthetic_layers

    folder = tmp_path / "layered"
    synthetic_layers(folder)
    open_and_wait(qtbot, window, folder)
    panel = window.layer_panel
    window.analysis_tabs.setCurrentWidget(panel)
    for radius in (1.0, 4.0, 7.0):
        window.set_radius(radius)
        qtbot.keyClick(window, Qt.Key.Key_P)
    assert window.layer_tab.picked == [1.0, 4.0, 7.0]
    panel.method_box.setCurrentIndex(panel.method_box.findData("radiance"))
    result = window.layer_tab.analysis.result
    np.testing.assert_allclose([layer.rgb for layer in result.layers], LAYER_UNIT, rtol=1e-4, atol=1e-5)
    for row, unit in enumerate(LAYER_UNIT):
        assert panel.table.item(row, 4).text() == "#%02x%02x%02x" % srgb_swatch(unit, "sRGB")

    # A rectangle region: the trajectory is the region mean of the stack, as core computes it.
    panel.region_box.setCurrentIndex(panel.region_box.findData("rectangle"))
    y0, x0, y1, x1 = window.image_panel.region_geometry()[1]
    expected = trajectory(window.stacks.pair.transient, rectangle_region((20, 20), y0, x0, y1, x1))
    np.testing.assert_allclose(panel.diagram.trajectory_xy(), expected.xy, atol=1e-12)
    assert window.layer_tab.region_description == f"rows {y0}..{y1 - 1}, columns {x0}..{x1 - 1}"

    # Clicking a trajectory point toggles its radius and moves the slider there.
    panel.radius_clicked.emit(4.0)
    assert window.layer_tab.picked == [1.0, 7.0] and window.scrub_bar.radius() == 4.0
    with qtbot.waitSignal(window.export_jobs.finished, timeout=LOAD_TIMEOUT_MS):
        window.layer_tab.export("json", tmp_path / "layers.json")
    document = json.loads((tmp_path / "layers.json").read_text())
    reference = recover_layers(expected, [1.0, 7.0], "radiance")
    np.testing.assert_allclose([layer["xy"] for layer in document["layers"]], [l.xy for l in reference.layers])
    with qtbot.waitSignal(window.export_jobs.finished, timeout=LOAD_TIMEOUT_MS):
        window.layer_tab.export("png", tmp_path / "diagram.png")
    assert cv2.imread(str(tmp_path / "diagram.png")).shape[0] > 100

    # A radius that is too dark to give a colour is reported, not crashed on.
    window.set_radius(8.0)
    qtbot.keyClick(window, Qt.Key.Key_P)
    assert "dark or negative" in panel.message_label.text() and window.layer_tab.analysis is None


def test_capture_wizard_runs_end_to_end_on_the_simulated_rig_and_opens_the_dataset(qtbot, window, tmp_path):
    from ringlight.app.main import main
    from test_capture import frame_files

    wizard, jobs = window.capture_wizard, window.capture_tab.jobs
    window.main_tabs.setCurrentWidget(wizard)
    assert wizard.camera_box.currentText() == "simulated" and wizard.projector_box.currentText() == "simulated"
    wizard.options_edit.setText("size=12x12 photons=300")
    with qtbot.waitSignal(jobs.finished, timeout=LOAD_TIMEOUT_MS):
        wizard.open_button.click()
    assert wizard.roi() == (0, 0, 12, 12) and wizard.pages.currentIndex() == 1
    with qtbot.waitSignal(jobs.finished, timeout=LOAD_TIMEOUT_MS):
        wizard.correspondence_button.click()
    assert "fit the homography" in wizard.correspondence_label.text()
    # The region can be typed or dragged on the projector view; the two stay in step.
    wizard.set_roi((2, 2, 10, 10))
    assert wizard.region_view.region_geometry() == ("rectangle", (2, 2, 10, 10))
    wizard.region_view.region_roi.setPos((3, 1))  # a drag: x 3, y 1
    assert wizard.roi() == (1, 3, 9, 11)
    wizard.set_roi((0, 0, 12, 12))
    wizard.radius_box.setValue(4.0)
    with qtbot.waitSignal(jobs.finished, timeout=LOAD_TIMEOUT_MS):
        wizard.probe_button.click()
    assert "81 frames instead of 144" in wizard.plan_label.text()
    wizard.out_edit.setText(str(tmp_path / "wizard"))
    with qtbot.waitSignal(jobs.finished, timeout=LOAD_TIMEOUT_MS):
        wizard.scan_button.click()
    assert wizard.scan_bar.value() == 1000 and wizard.open_dataset_button.isEnabled()
    with qtbot.waitSignal(window.dataset_loaded, timeout=LOAD_TIMEOUT_MS):
        wizard.open_dataset_button.click()
    assert window.loaded.dataset.path == tmp_path / "wizard" and window.main_tabs.currentIndex() == 0
    # The command line runs the same steps: the same rig gives the same dataset, bit for bit.
    assert main(["capture", "--camera", "simulated", "--projector", "simulated", "--option", "size=12x12",
                 "--option", "photons=300", "--max-radius", "4", "--out", str(tmp_path / "cli")]) == 0
    assert frame_files(tmp_path / "wizard") == frame_files(tmp_path / "cli")


def test_capture_steps_out_of_order_explain_what_is_missing(qtbot, window):
    with qtbot.waitSignal(window.error_shown, timeout=5000) as error:
        window.capture_wizard.correspondence_button.click()
    assert "Open the devices first" in error.args[0]
