"""The window's controls and readouts always describe the dataset and stack on screen."""

import json

import numpy as np
import pytest
from plain_view import plain_settings
from reference import random_impulses, write_dataset
from ringlight.app.window import MainWindow
from ringlight.core.rings.stack_request import StackRequest, largest_stop

TIMEOUT_MS = 120_000


@pytest.fixture
def window(qtbot, tmp_path):
    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    window.activateWindow()  # shortcuts need the active window under a real X server
    yield window
    window.shutdown()


def make_dataset(folder, size, max_radius, seed):
    impulses = random_impulses(np.random.default_rng(seed), size, size, support=max_radius)
    write_dataset(folder, size, size, impulses, max_radius=max_radius)
    return folder


def open_and_wait(qtbot, window, path):
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(path)


def test_a_small_dataset_does_not_clamp_the_next_ones_stack(qtbot, window, tmp_path):
    small = make_dataset(tmp_path / "small", 9, 3, seed=1)
    large = make_dataset(tmp_path / "large", 12, 8, seed=2)
    # r1 + dr + w/2 must stay within max_radius: 6 for max_radius 8, 1 for max_radius 3.
    large_stop, small_stop = largest_stop(8, StackRequest(0.0, 0.0)), largest_stop(3, StackRequest(0.0, 0.0))
    assert (large_stop, small_stop) == (6.0, 1.0)
    open_and_wait(qtbot, window, large)
    assert window.stack_controls.request().stop == large_stop
    open_and_wait(qtbot, window, small)
    assert window.stack_controls.request().stop == small_stop
    open_and_wait(qtbot, window, large)
    assert window.stack_controls.request().stop == large_stop  # its own request, not the small one's clamp
    window.save_settings()
    again = MainWindow(window.settings)
    qtbot.addWidget(again)
    try:
        assert again.saved_request(large).stop == large_stop and again.saved_request(small).stop == small_stop
    finally:
        again.shutdown()


def test_the_demo_dataset_remembers_its_stack_like_any_other(qtbot, window, tmp_path):
    open_and_wait(qtbot, window, None)  # the demo, opened without a path
    chosen = window.stacks.pair.request.with_changes(step=0.5, stop=2.0)
    assert chosen != window.stacks.pair.request
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.request_stacks(chosen)
    open_and_wait(qtbot, window, make_dataset(tmp_path / "other", 9, 3, seed=4))
    open_and_wait(qtbot, window, None)
    assert window.stacks.pair.request == chosen  # was the default: it was saved under a key never read
    assert window.stack_controls.request() == chosen


def test_a_saved_stack_the_dataset_cannot_serve_is_replaced_by_the_default_with_a_notice(qtbot, window, tmp_path):
    folder = make_dataset(tmp_path / "d", 12, 8, seed=5)
    open_and_wait(qtbot, window, folder)
    default = window.stacks.pair.request
    far = default.with_changes(stop=6.0)
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.request_stacks(far)
    open_and_wait(qtbot, window, make_dataset(tmp_path / "other", 9, 3, seed=6))  # remembers `far`
    document = json.loads((folder / "dataset.json").read_text())
    document["max_radius"] = 4.0  # the dataset changed since: `far` now reaches beyond it
    (folder / "dataset.json").write_text(json.dumps(document))
    assert far.reach() > 4.0
    open_and_wait(qtbot, window, folder)
    notice = window.statusBar().currentMessage()
    assert notice.startswith("The stack last shown for d cannot be made now (") and "max_radius 4" in notice
    assert window.stacks.pair.request.reach() <= 4.0 and window.stack_controls.request() == window.stacks.pair.request


@pytest.mark.parametrize("change", [{"stop": 12.0}, {"antialias": True}])
def test_a_refused_request_leaves_the_controls_showing_the_stack_on_screen(qtbot, window, tmp_path, change):
    open_and_wait(qtbot, window, make_dataset(tmp_path / "d", 9, 3, seed=3))
    shown = window.stacks.pair.request.with_changes(step=0.5, stop=1.5)  # reaches 3 without anti-aliasing
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.request_stacks(shown)
    refused = shown.with_changes(**change)
    assert refused.reach() > 3 >= shown.reach()  # r1 = 12, or anti-aliasing's wider rings, pass max_radius 3
    window.stack_controls.set_request(refused)
    with qtbot.waitSignal(window.error_shown, timeout=TIMEOUT_MS):
        window.request_stacks(refused)
    assert "max_radius" in window.last_error
    assert window.stack_controls.request() == shown == window.stacks.pair.request


def test_opening_another_dataset_resets_pick_hover_and_diagram(qtbot, window, tmp_path):
    open_and_wait(qtbot, window, make_dataset(tmp_path / "a", 12, 4, seed=4))
    window.pick(1, 2)
    window.hover_label.setText(window.describe_pixel(1, 2))
    window.layer_panel.diagram.setRange(xRange=(0.3, 0.31), yRange=(0.3, 0.31), padding=0)
    open_and_wait(qtbot, window, make_dataset(tmp_path / "b", 10, 4, seed=5))
    assert window.picked == (5, 5)  # the new dataset's centre
    assert window.hover_label.text() == ""
    (x0, x1), (y0, y1) = window.layer_panel.diagram.getPlotItem().vb.viewRange()
    assert x0 <= 0.0 and x1 >= 0.8 and y0 <= 0.0 and y1 >= 0.9  # the whole CIE diagram


@pytest.mark.parametrize("compiled", [True, False])
def test_an_empty_window_says_what_it_is_opening_and_marks_no_radius_until_there_are_profiles(qtbot, window,
                                                                                           tmp_path, monkeypatch,
                                                                                           compiled):
    from ringlight.app import dataset_opening

    # A fresh install's first start (numba's cache empty) also says why the open takes a minute.
    monkeypatch.setattr(dataset_opening, "kernels_compiled", lambda: compiled)
    assert not any(line.isVisible() for line in window.profile_plot.radius_lines)
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(make_dataset(tmp_path / "d", 9, 3, seed=6))
        expected = "Opening d ..." + ("" if compiled else "\n" + dataset_opening.FIRST_START)
        assert window.image_panel.title.toPlainText() == expected
    assert all(line.isVisible() for line in window.profile_plot.radius_lines)
    assert window.profile_plot.radius_lines[0].value() == window.stacks.pair.radii[window.radius_index()]


def test_cancelling_the_first_open_leaves_a_hint_not_a_blank_window(qtbot, window, tmp_path):
    from ringlight.app.dataset_opening import EMPTY_HINT

    with qtbot.waitSignal(window.load_jobs.idle, timeout=TIMEOUT_MS):
        window.open_dataset(make_dataset(tmp_path / "d", 9, 3, seed=6))
        window.cancel_all()
    assert window.loaded is None
    assert window.image_panel.title.toPlainText() == EMPTY_HINT
    assert window.statusBar().currentMessage() == "Opening cancelled; nothing of it was kept. " + EMPTY_HINT


def test_an_open_superseded_by_another_is_not_reported_cancelled(qtbot, window, tmp_path):
    first, second = make_dataset(tmp_path / "a", 9, 3, seed=6), make_dataset(tmp_path / "b", 9, 3, seed=7)
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(first)
        window.open_dataset(second)  # cancels the first
        assert "cancelled" not in window.statusBar().currentMessage()
    assert window.loaded.dataset.path == second
    assert "cancelled" not in window.statusBar().currentMessage()


def test_shortcut_sheet_lists_every_menu_shortcut(window):
    from PySide6.QtGui import QKeySequence

    sheet = "\n".join(window.shortcut_lines())
    shortcuts = [action.shortcut().toString(QKeySequence.SequenceFormat.NativeText)
                 for menu in window.menuBar().actions() for action in menu.menu().actions()]
    shortcuts = [keys for keys in shortcuts if keys]
    assert len(shortcuts) >= 15
    for keys in shortcuts:
        assert keys in sheet
    assert "Ctrl+O" in sheet and "Export stack as EXR" in sheet


def test_truth_panel_zooms_and_pans_with_the_image(qtbot, window, tmp_path):
    window.truth_panel.show()
    qtbot.waitUntil(lambda: window.truth_panel.isVisible())
    window.image_panel.view.setRange(xRange=(2, 5), yRange=(1, 4), padding=0)
    image, truth = window.image_panel.view.viewRange(), window.truth_panel.view.viewRange()
    for axis in range(2):  # the same part of the grid in the middle of both panels
        assert abs(sum(image[axis]) / 2 - sum(truth[axis]) / 2) < 0.05 * (image[axis][1] - image[axis][0])


@pytest.mark.parametrize("target, length", [(0.64, 0.5), (3.2, 2.0), (1.0, 1.0), (7.9, 5.0), (12.0, 10.0)])
def test_scale_bar_takes_the_round_length_below_a_fifth_of_the_width(target, length):
    from ringlight.widgets.image_panel import scale_bar_length

    assert scale_bar_length(target) == length


def test_scale_bar_shows_millimetres_when_the_pitch_is_known(qtbot, window, tmp_path):
    folder = make_dataset(tmp_path / "d", 32, 3, seed=7)
    manifest = json.loads((folder / "dataset.json").read_text())
    manifest["grid"]["pitch_mm"] = 0.1  # 32 steps = 3.2 mm: a fifth is 0.64 mm, the bar 0.5 mm = 5 steps
    (folder / "dataset.json").write_text(json.dumps(manifest))
    open_and_wait(qtbot, window, folder)
    bar = window.image_panel.scale_bar
    assert bar.text.toPlainText() == "0.5 mm" and bar.size == pytest.approx(5.0)
    # Another dataset after one with a pitch: the old bar goes (pyqtgraph's ScaleBar raised while
    # being detached, and the open never finished).
    open_and_wait(qtbot, window, make_dataset(tmp_path / "e", 12, 4, seed=8))
    assert window.image_panel.scale_bar is None and bar.scene() is None


def test_region_statistics_of_the_shown_image(qtbot, window, tmp_path):
    from ringlight.core.colour.regions import rectangle_region, region_statistics

    open_and_wait(qtbot, window, make_dataset(tmp_path / "d", 12, 4, seed=8))
    window.layer_tab.region = rectangle_region((12, 12), 2, 3, 6, 9)  # rows 2..5, columns 3..8
    window.show_region_statistics()
    image = window.current_image()[2:6, 3:9].reshape(-1, 3).astype(np.float64)
    image = image[np.isfinite(image).all(axis=1)]  # brute force over the rectangle
    assert f"region: {len(image)} px, mean RGB {' '.join(f'{m:.4g}' for m in image.mean(0))}" in window.region_label.text()
    count, mean, std = region_statistics(window.current_image(), window.layer_tab.region)
    np.testing.assert_allclose(std, image.std(0), rtol=1e-9)


def test_dragging_the_levels_histogram_sets_manual_levels(qtbot, window, tmp_path):
    from ringlight.core.colour.display import render, value_histogram

    open_and_wait(qtbot, window, make_dataset(tmp_path / "d", 12, 4, seed=9))
    image = window.current_image()
    edges, counts = value_histogram(image)
    assert counts.sum() == np.isfinite(image).sum()  # every finite channel value is counted
    low, high = float(edges[10]), float(edges[90])
    region = window.levels_histogram.region
    region.setRegion((low, high))
    region.sigRegionChangeFinished.emit(region)  # the end of a drag
    settings = window.display_settings()
    assert settings.normalisation == "manual"
    np.testing.assert_allclose(settings.manual_levels, (low, high), rtol=1e-5)
    expected = render(image, settings.manual_levels, settings, window.loaded.dataset.colorspace)
    np.testing.assert_array_equal(window.image_panel.pixels(), expected)


@pytest.mark.parametrize("measure_line, notice", [("", True), ("\nmeasure: camera", False)])
def test_a_dataset_simulated_as_exitance_is_flagged_when_opened(qtbot, window, tmp_path, measure_line, notice):
    from PySide6.QtWidgets import QMessageBox

    folder = make_dataset(tmp_path / "legacy", 9, 3, seed=10)
    manifest = json.loads((folder / "dataset.json").read_text())
    manifest["notes"] = "simulated by ringlight from preset red-bead" + measure_line
    manifest["ground_truth"] = {"layers": [{"name": "top", "depth": [0, 1], "rgb": [0.5, 0.5, 0.5]}]}
    (folder / "dataset.json").write_text(json.dumps(manifest))
    open_and_wait(qtbot, window, folder)
    titles = [box.windowTitle() for box in window.findChildren(QMessageBox) if box.isVisible()]
    assert ("Simulated before camera radiance" in titles) == notice
    for box in window.findChildren(QMessageBox):
        box.close()


def test_view_as_shown_export_has_the_panel_size_and_the_ring_overlay(qtbot, window, tmp_path):
    import cv2
    from ringlight.widgets.image_panel import MEMBER_RGB

    open_and_wait(qtbot, window, make_dataset(tmp_path / "d", 12, 4, seed=11))
    window.pick(6, 6)
    out = tmp_path / "shown.png"
    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.export_shown(out)
    pixels = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    ratio = window.image_panel.devicePixelRatioF()
    assert pixels.shape[:2] == (round(window.image_panel.height() * ratio), round(window.image_panel.width() * ratio))
    window.image_panel.clear_ring()
    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.export_shown(tmp_path / "bare.png")
    bare = cv2.cvtColor(cv2.imread(str(tmp_path / "bare.png")), cv2.COLOR_BGR2RGB)

    def ring_coloured(image):
        return int((np.abs(image.astype(int) - np.array(MEMBER_RGB)).sum(-1) < 30).sum())
    # The ring's circle, drawn in MEMBER_RGB, is in the export and not in one without the ring.
    assert ring_coloured(pixels) > ring_coloured(bare) + 50


def test_the_diagram_png_is_the_whole_diagram_whatever_the_zoom(qtbot, window, tmp_path):
    open_and_wait(qtbot, window, make_dataset(tmp_path / "d", 12, 4, seed=5))
    window.analysis_tabs.setCurrentWidget(window.layer_panel)
    diagram = window.layer_panel.diagram
    diagram.reset_view()
    whole = np.array(diagram.getPlotItem().vb.viewRange())
    diagram.setRange(xRange=(0.30, 0.35), yRange=(0.30, 0.35), padding=0)
    zoomed = np.array(diagram.getPlotItem().vb.viewRange())
    grabbed, grab = [], diagram.grab
    diagram.grab = lambda *args: (grabbed.append(np.array(diagram.getPlotItem().vb.viewRange())), grab(*args))[1]
    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.layer_tab.export("png", tmp_path / "diagram.png")
    assert len(grabbed) == 1 and np.allclose(grabbed[0], whole)  # drawn whole for the file
    restored = np.array(diagram.getPlotItem().vb.viewRange())  # and the user's zoom is back
    assert np.allclose(restored.mean(1), zoomed.mean(1)) and np.allclose(np.ptp(restored, 1), np.ptp(zoomed, 1), rtol=0.1)
    assert (tmp_path / "diagram.png").stat().st_size > 1000


def test_a_shut_down_window_starts_no_more_work(qtbot, window, tmp_path):
    """Destroying a window's widgets emits the signals that start jobs (a view change asks for
    the noise): once shut down it starts none, so no job can outlive it (one blocked forever in
    the store's reader after the interpreter's exit-time clean-up, and the exit hung)."""
    open_and_wait(qtbot, window, make_dataset(tmp_path / "d", 12, 4, seed=6))
    window.shutdown()
    window.noise = None
    window.display_controls.set_view("ring")  # would ask for the noise again
    window.request_stacks(window.stacks.pair.request)
    window.capture_tab.open_devices("simulated", "simulated", "size=4x4 photons=10")
    assert not any(slot.busy for slot in (window.noise_jobs, window.stack_jobs, window.capture_tab.jobs))
    assert window.pool.activeThreadCount() == 0 and window.capture_pool.activeThreadCount() == 0


def test_a_stack_asked_for_while_a_dataset_opens_is_computed_once_it_is_open(qtbot, window, tmp_path):
    """The stack controls edited during an open: the open's own stacks come first, then the edit
    is computed (it was overwritten by the open's request)."""
    from ringlight.core.rings.stack_request import StackRequest

    edited = StackRequest(start=0.0, stop=1.5, step=0.5)  # its reach, 3, within max_radius 3
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(make_dataset(tmp_path / "d", 9, 3, seed=8))
        assert window.load_jobs.busy
        window.stack_controls.set_request(edited)
        window.stack_controls.request_changed.emit(window.stack_controls.request())  # the edit settles
    qtbot.waitUntil(lambda: window.stacks.pair.request == edited, timeout=30_000)
    assert window.stack_controls.request() == edited
    assert window.stacks.pair.radii.tolist() == [0.0, 0.5, 1.0, 1.5]
