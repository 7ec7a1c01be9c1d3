"""The explorer fits a 1366 x 768 laptop screen (window frame and task bar left aside): no panel
asks for more, and nothing drawn in the panels is clipped at the window's first or minimum size."""

import numpy as np
import pytest

pytest.importorskip("PySide6")
from PySide6.QtCore import QRectF, Qt  # noqa: E402
from plain_view import plain_settings  # noqa: E402
from reference import random_impulses, write_dataset, write_rgb  # noqa: E402
from ringlight.app.window import MainWindow  # noqa: E402


def test_every_panel_fits_a_1366_by_768_screen(qtbot, tmp_path):
    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    try:
        hint = window.minimumSizeHint()
        # Measured 1295 x 677 offscreen: three docks beside the capture wizard's live-view page
        # (1349 while the Colour page's buttons read in full; 1645 before two-row Layers controls).
        assert hint.width() <= 1366 - 16 and hint.height() <= 768 - 48
        for tab in range(window.main_tabs.count()):
            window.main_tabs.setCurrentIndex(tab)
            assert window.minimumSizeHint().width() <= 1366 - 16
    finally:
        window.shutdown()


# What the window shows first on a 1366 x 768 screen (first_size: the screen less 16 x 48).
FIRST_SIZE = (1366 - 16, 768 - 48)


@pytest.fixture
def truth_dataset(tmp_path):
    """A 12 x 12 dataset with 4 ground-truth bins, so that the truth panel is shown."""
    folder = tmp_path / "dataset"
    rng = np.random.default_rng(5)
    entries = []
    for index in range(4):
        write_rgb(folder / f"truth/len_{index:03d}.exr", rng.uniform(0, 1, (12, 12, 3)).astype(np.float32))
        entries.append({"file": f"truth/len_{index:03d}.exr", "min": float(index), "max": float(index + 1)})
    write_dataset(folder, 12, 12, random_impulses(rng, 12, 12, support=4.0), max_radius=4.0,
                  extra={"ground_truth": {"path_length_images": entries}})
    return folder


def resize_and_wait(qtbot, window, size) -> None:
    window.resize(*size)
    qtbot.waitUntil(lambda: (window.width(), window.height()) == tuple(size))
    qtbot.wait(50)  # the docks and pyqtgraph's layouts settle


def opened(qtbot, window, folder):
    with qtbot.waitSignal(window.dataset_loaded, timeout=120_000):
        window.open_dataset(folder)
    return window


def sizes_to_check(qtbot, window) -> dict:
    qtbot.wait(50)  # the layouts take in what was just shown
    hint = window.minimumSizeHint()
    return {"first": FIRST_SIZE, "minimum": (hint.width(), hint.height())}


def inside_view(view, scene_rect) -> bool:
    """Whether ``scene_rect`` (scene coordinates) is drawn wholly inside ``view``'s viewport."""
    return QRectF(view.viewport().rect()).contains(view.mapFromScene(scene_rect).boundingRect().toRectF())


def test_the_profile_plots_are_not_clipped_at_the_first_or_the_minimum_size(qtbot, window, truth_dataset):
    opened(qtbot, window, truth_dataset)
    plot = window.profile_plot
    plot.set_point("at y 999 x 999")  # the widest point label of a paper-sized grid
    for name, size in {**sizes_to_check(qtbot, window), "narrowest dock": None}.items():
        if size is None:
            window.resizeDocks([window.profile_dock], [1], Qt.Orientation.Horizontal)
            qtbot.wait(50)
        else:
            resize_and_wait(qtbot, window, size)
        # Measured offscreen at 1350 x 720: the layout needed 414 px (the T(r) title alone 330) in a
        # 386 px view, at 1295 x 696 in 331 px; now it needs 294 px.
        assert plot.ci.geometry().width() <= plot.viewport().width(), name
        for item in (plot.ring_plot, plot.transient_plot, plot.point_label,
                     plot.ring_plot.titleLabel, plot.transient_plot.titleLabel,
                     plot.transient_plot.getAxis("bottom")):
            assert inside_view(plot, item.sceneBoundingRect()), (name, item)


@pytest.mark.parametrize("method", ["paper", "inverse"])
def test_the_chromaticity_key_lies_inside_the_diagram_and_off_the_plot(qtbot, window, truth_dataset, method):
    opened(qtbot, window, truth_dataset)
    window.analysis_tabs.setCurrentWidget(window.layer_panel)
    panel = window.layer_panel
    panel.method_box.setCurrentIndex(panel.method_box.findData(method))
    diagram = panel.diagram
    key = diagram.getPlotItem().titleLabel
    for name, size in sizes_to_check(qtbot, window).items():
        resize_and_wait(qtbot, window, size)
        # Before: the key, one line 390 px wide anchored at the right, began 20-80 px left of a 313-368 px view;
        # then, inside the plot at its top right, it covered the top layer of layers3 in the Layers tab.
        assert diagram.getPlotItem().sceneBoundingRect().width() <= diagram.viewport().width(), name
        assert inside_view(diagram, key.item.sceneBoundingRect()), (name, key.item.sceneBoundingRect())
        assert not key.item.sceneBoundingRect().intersects(diagram.getPlotItem().vb.sceneBoundingRect()), name
        assert key.item.sceneBoundingRect().width() > 100  # a key that is there, not an empty one


def test_image_and_truth_panels_are_equal_and_stay_equal_until_dragged(qtbot, window, truth_dataset):
    opened(qtbot, window, truth_dataset)
    splitter = window.splitter
    qtbot.waitUntil(lambda: window.truth_panel.isVisible())
    for size in (FIRST_SIZE, (1366, 768), sizes_to_check(qtbot, window)["minimum"]):
        resize_and_wait(qtbot, window, size)
        image, truth = splitter.sizes()
        # Before: 360 and 240 px at 1350 x 720 (the truth panel got its size hint when shown).
        assert abs(image - truth) <= 1 and image > 200, (size, image, truth)
    window.profile_dock.hide()
    qtbot.waitUntil(lambda: sum(splitter.sizes()) > 2 * image + 100)
    assert abs(splitter.sizes()[0] - splitter.sizes()[1]) <= 1  # more room: shared alike
    window.profile_dock.show()
    splitter.moveSplitter(splitter.sizes()[0] - 60, 1)  # the user drags the handle 60 px left
    dragged = splitter.sizes()
    assert dragged[1] - dragged[0] >= 100
    resize_and_wait(qtbot, window, FIRST_SIZE)
    assert splitter.sizes()[1] - splitter.sizes()[0] == dragged[1] - dragged[0]  # the user's choice stays


def test_nothing_resizes_the_window_by_itself(qtbot, window, truth_dataset, tmp_path):
    """At the first size and at the minimum one (where any growth of a panel would show), no
    open, radius or view change, notice, dock or tab changes the window's size."""
    second = tmp_path / "second"
    write_dataset(second, 20, 16, random_impulses(np.random.default_rng(6), 20, 16, support=6.0), max_radius=6.0)
    opened(qtbot, window, truth_dataset)
    for size in sizes_to_check(qtbot, window).values():
        resize_and_wait(qtbot, window, size)
        controls = window.display_controls
        steps = [
            lambda: window.set_radius(2.0),
            lambda: controls.shown_box.setCurrentIndex(controls.shown_box.findData("R")),  # notice of negatives
            lambda: controls.shown_box.setCurrentIndex(controls.shown_box.findData("signed")),
            lambda: controls.set_view("difference"),
            lambda: controls.set_view("snr"),
            lambda: controls.set_view("transient"),
            lambda: window.line_profile_dock.toggleViewAction().trigger(),
            lambda: window.line_profile_dock.toggleViewAction().trigger(),
            lambda: window.analysis_tabs.setCurrentWidget(window.layer_panel),
            lambda: window.analysis_tabs.setCurrentIndex(0),
            lambda: opened(qtbot, window, second),
            lambda: opened(qtbot, window, truth_dataset),
        ]
        for step in steps:
            step()
            qtbot.wait(30)
            assert (window.width(), window.height()) == tuple(size), steps.index(step)
