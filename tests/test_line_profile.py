"""The line-profile tool samples the data along the line as drawn on the image panel.

The reference is analytic: pixel (i, j) of :data:`RAMP` holds a linear function of its centre
(i + 0.5, j + 0.5), so bilinear interpolation between pixel centres reproduces that function
exactly at any point between them. The grid is not square and each channel has its own y and x
factors, so sampling transposed, or half a pixel off, gives other numbers.
"""

import math
import time

import numpy as np
import pytest

pytest.importorskip("PySide6")
import pyqtgraph as pg  # noqa: E402
from PySide6.QtCore import QEvent, QPoint, QPointF, Qt  # noqa: E402
from PySide6.QtGui import QMouseEvent  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

from qt_paints import PaintCounter  # noqa: E402
from ringlight.core.atomic import OutputError  # noqa: E402
from ringlight.widgets.image_panel import ImagePanel  # noqa: E402
from ringlight.widgets.line_profile import DISTANCE_LABEL, LineProfilePlot, LineProfileTool  # noqa: E402

HEIGHT, WIDTH = 40, 60
Y_FACTORS = np.array([3.0, -1.0, 0.5])
X_FACTORS = np.array([2.0, 4.0, -3.0])
OFFSETS = np.array([0.0, 100.0, 200.0])


def ramp_at(y, x) -> np.ndarray:
    """(N, 3) values of the ramp at (N,) grid coordinates ``y``, ``x``."""
    return (np.asarray(y, np.float64)[:, None] * Y_FACTORS + np.asarray(x, np.float64)[:, None] * X_FACTORS
            + OFFSETS)


_rows, _columns = np.mgrid[0:HEIGHT, 0:WIDTH]
RAMP = ramp_at(_rows.ravel() + 0.5, _columns.ravel() + 0.5).reshape(HEIGHT, WIDTH, 3)
"""(H, W, 3) float64: each pixel holds the ramp at its centre."""


def display_pixels(data: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 pixels of ``data`` scaled per channel to 0..255 (only for drawing)."""
    low, high = data.min(axis=(0, 1)), data.max(axis=(0, 1))
    return np.round(255 * (data - low) / (high - low)).astype(np.uint8)


def expected_profile(start, end) -> tuple[np.ndarray, np.ndarray]:
    """Distances and ramp values at ceil(length) + 1 points evenly spaced from ``start`` to ``end``."""
    length = math.hypot(end[0] - start[0], end[1] - start[1])
    count = math.ceil(length) + 1
    fraction = np.linspace(0, 1, count)
    y = start[0] + fraction * (end[0] - start[0])
    x = start[1] + fraction * (end[1] - start[1])
    return fraction * length, ramp_at(y, x)


@pytest.fixture
def panel(qtbot):
    panel = ImagePanel()
    qtbot.addWidget(panel)
    panel.resize(480, 360)
    panel.set_pixels(display_pixels(RAMP))
    return panel


@pytest.fixture
def tool(qtbot, panel):
    tool = LineProfileTool(panel)
    qtbot.addWidget(tool.plot_widget)
    tool.set_data(RAMP)
    tool.set_enabled(True)
    return tool


LINES = {
    "horizontal": ((20.5, 5.5), (20.5, 50.5)),
    "vertical": ((3.5, 30.5), (36.5, 30.5)),
    "diagonal": ((4.2, 7.3), (33.9, 51.1)),
    "diagonal backwards": ((35.0, 52.75), (1.25, 2.0)),
}


@pytest.mark.parametrize("name", LINES)
def test_profile_equals_the_ramp_at_the_sample_points(tool, name):
    start, end = LINES[name]
    tool.set_line(start, end)
    distances, values = tool.profile()
    want_distances, want_values = expected_profile(start, end)
    assert distances.dtype == values.dtype == np.float64
    assert values.shape == (len(want_distances), 3)
    np.testing.assert_allclose(distances, want_distances, atol=1e-9)
    np.testing.assert_allclose(values, want_values, atol=1e-4)


@pytest.mark.parametrize("name", LINES)
def test_distances_run_from_zero_to_the_length_in_steps_of_at_most_one(tool, name):
    start, end = LINES[name]
    tool.set_line(start, end)
    distances, _ = tool.profile()
    assert distances[0] == 0.0
    assert distances[-1] == pytest.approx(math.hypot(end[0] - start[0], end[1] - start[1]), abs=1e-9)
    assert np.all(np.diff(distances) > 0) and np.all(np.diff(distances) <= 1 + 1e-12)


def test_first_line_is_horizontal_through_the_middle_row_over_60_percent_of_the_width(tool):
    (y0, x0), (y1, x1) = tool.line()
    assert (y0, y1) == (HEIGHT // 2 + 0.5,) * 2  # the centres of the middle row
    assert (x0, x1) == (12.5, 48.5)  # 20 % and 80 % of 60, on pixel centres: 36 = 0.6 x 60 steps
    assert tool.roi in tool.panel.view.addedItems
    _, values = tool.profile()
    np.testing.assert_allclose(values, RAMP[HEIGHT // 2, 12:49], atol=1e-12)  # the row's own pixels


def test_dragging_a_handle_resamples_the_new_line(qtbot, tool):
    tool.set_line(*LINES["horizontal"])
    view, handle = tool.panel.view, tool.roi.getHandles()[1]
    with qtbot.waitSignal(tool.profile_changed, timeout=1000):
        # What the handle's mouseDragEvent calls: the new position in scene coordinates.
        handle.movePoint(view.mapViewToScene(QPointF(57.0, 38.25)))
    start = LINES["horizontal"][0]
    assert tool.line() == (start, (38.25, 57.0))
    distances, values = tool.profile()
    want_distances, want_values = expected_profile(start, (38.25, 57.0))
    np.testing.assert_allclose(distances, want_distances, atol=1e-9)
    np.testing.assert_allclose(values, want_values, atol=1e-4)


def _mouse(panel: ImagePanel, kind: QEvent.Type, position: QPoint, buttons: Qt.MouseButton) -> None:
    """Send a mouse event at widget ``position`` to the panel's viewport, 30 ms after the last:
    pyqtgraph's scene drops moves closer than 10 ms (its ``mouseRateLimit``)."""
    time.sleep(0.03)
    button = Qt.MouseButton.NoButton if kind == QEvent.Type.MouseMove else Qt.MouseButton.LeftButton
    global_position = QPointF(panel.viewport().mapToGlobal(position))
    QApplication.sendEvent(panel.viewport(), QMouseEvent(kind, QPointF(position), global_position, button, buttons,
                                                         Qt.KeyboardModifier.NoModifier))


def test_a_mouse_drag_on_a_handle_moves_that_end_and_picks_no_pixel(qtbot, panel, tool):
    panel.show()
    qtbot.waitExposed(panel)
    picked = []
    panel.pixel_picked.connect(lambda y, x: picked.append((y, x)))
    start, (y1, x1) = tool.line()
    handle, target = (panel.mapFromScene(panel.view.mapViewToScene(QPointF(x, y))) for y, x in ((y1, x1), (35.0, 55.0)))
    move, none, left = QEvent.Type.MouseMove, Qt.MouseButton.NoButton, Qt.MouseButton.LeftButton
    for position in (handle + QPoint(1, 0), handle):  # hovering tells pyqtgraph the handle takes drags
        _mouse(panel, move, position, none)
    _mouse(panel, QEvent.Type.MouseButtonPress, handle, left)
    for step in np.linspace(0, 1, 6):
        _mouse(panel, move, handle + (target - handle) * step, left)
    _mouse(panel, QEvent.Type.MouseButtonRelease, target, none)
    new_start, new_end = tool.line()
    assert new_start == start and picked == []
    np.testing.assert_allclose(new_end, (35.0, 55.0), atol=0.25)  # within a screen pixel
    np.testing.assert_allclose(tool.profile()[1], expected_profile(start, new_end)[1], atol=1e-4)


def test_moving_the_whole_line_resamples_it_where_it_is_now(qtbot, tool):
    start, end = LINES["diagonal"]
    tool.set_line(start, end)
    with qtbot.waitSignal(tool.profile_changed, timeout=1000):
        tool.roi.translate((-3.0, 2.5))  # (x, y), as dragging the line's body does
    moved_start, moved_end = (start[0] + 2.5, start[1] - 3.0), (end[0] + 2.5, end[1] - 3.0)
    np.testing.assert_allclose(tool.line(), (moved_start, moved_end), atol=1e-12)
    np.testing.assert_allclose(tool.profile()[1], expected_profile(moved_start, moved_end)[1], atol=1e-4)


def test_new_data_are_profiled_along_the_same_line_and_a_new_grid_size_resets_it(qtbot, tool):
    tool.set_line(*LINES["vertical"])
    with qtbot.waitSignal(tool.profile_changed, timeout=1000):
        tool.set_data(2 * RAMP)
    np.testing.assert_allclose(tool.profile()[1], 2 * expected_profile(*LINES["vertical"])[1], atol=1e-4)
    tool.set_data(RAMP[:10, :30])
    assert tool.line() == ((5.5, 6.5), (5.5, 24.5))  # the default line of a 10 x 30 grid
    np.testing.assert_allclose(tool.profile()[1], RAMP[5, 6:25], atol=1e-12)


def test_scalar_data_give_one_column_and_one_curve(tool):
    tool.set_data(RAMP[..., 1])
    tool.set_line(*LINES["diagonal"])
    distances, values = tool.profile()
    np.testing.assert_allclose(values, expected_profile(*LINES["diagonal"])[1][:, 1:2], atol=1e-4)
    plot = tool.plot_widget
    np.testing.assert_array_equal(plot.scalar_curve.getData()[1], values[:, 0])
    assert all(curve.getData() == (None, None) for curve in plot.rgb_curves)  # pyqtgraph's "no data"


def test_the_plot_shows_the_profile_and_names_the_ends_and_the_length(tool):
    tool.set_line(*LINES["horizontal"])
    distances, values = tool.profile()
    plot = tool.plot_widget
    for channel, curve in enumerate(plot.rgb_curves):
        x, y = curve.getData()
        np.testing.assert_array_equal(x, distances)
        np.testing.assert_array_equal(y, values[:, channel])
    colours = [pg.mkPen(curve.opts["pen"]).color().getRgb()[:3] for curve in plot.rgb_curves]
    assert [int(np.argmax(colour)) for colour in colours] == [0, 1, 2]  # red, green, blue
    title = plot.plot.titleLabel.text
    assert "(y 20.5, x 5.5)" in title and "(y 20.5, x 50.5)" in title and "length 45.0 grid steps" in title
    assert plot.plot.getAxis("bottom").labelText == DISTANCE_LABEL


def test_off_removes_the_line_and_clears_the_plot_and_on_brings_both_back(qtbot, tool):
    tool.set_line(*LINES["diagonal"])
    before = tool.profile()
    with qtbot.waitSignal(tool.profile_changed, timeout=1000):
        tool.set_enabled(False)
    assert tool.roi.scene() is None and tool.roi not in tool.panel.view.addedItems
    assert tool.line() == LINES["diagonal"]  # kept for when it is on again
    assert tool.profile()[0].shape == (0,)
    assert all(curve.getData() == (None, None) for curve in tool.plot_widget.rgb_curves)
    assert tool.plot_widget.plot.titleLabel.text == ""
    tool.set_data(2 * RAMP)  # while off: kept, not sampled
    assert tool.profile()[0].shape == (0,)
    tool.set_enabled(True)
    assert tool.roi.scene() is tool.panel.scene()
    np.testing.assert_allclose(tool.profile()[1], 2 * before[1], atol=1e-12)


def test_outside_the_image_is_nan_and_its_outer_half_pixel_is_the_edge_pixel(tool):
    tool.set_line((20.5, -3.0), (20.5, 0.25))  # 5 points: x = -3, -2.1875, -1.375, -0.5625, 0.25
    _, values = tool.profile()
    assert np.isnan(values[:4]).all()
    np.testing.assert_allclose(values[4], RAMP[20, 0], atol=1e-12)  # left of the first centre


def test_a_nan_pixel_spoils_only_the_samples_it_weighs_in(tool):
    data = RAMP.copy()
    data[21, 30] = np.nan
    tool.set_data(data)
    tool.set_line((20.5, 5.5), (20.5, 50.5))  # the centres of row 20, next to the NaN pixel
    np.testing.assert_allclose(tool.profile()[1], RAMP[20, 5:51], atol=1e-12)
    tool.set_line((21.5, 5.5), (21.5, 50.5))  # across it: only the sample on its centre
    _, values = tool.profile()
    assert np.isnan(values[25]).all()
    np.testing.assert_allclose(np.delete(values, 25, axis=0), np.delete(RAMP[21, 5:51], 25, axis=0), atol=1e-12)


def test_profile_equals_pyqtgraph_bilinear_interpolation_on_random_data(tool):
    # Reference: pyqtgraph's own interpolateArray, its values at indices (i, j) being pixel centres.
    data = np.random.default_rng(15).normal(size=(HEIGHT, WIDTH, 3))
    tool.set_data(data)
    start, end = (2.7, 3.1), (37.2, 55.9)
    tool.set_line(start, end)
    distances, values = tool.profile()
    fraction = distances / distances[-1]
    indices = np.column_stack([start[0] + fraction * (end[0] - start[0]),
                               start[1] + fraction * (end[1] - start[1])]) - 0.5
    np.testing.assert_allclose(values, pg.functions.interpolateArray(data, indices, order=1), atol=1e-12)


def test_save_csv_writes_a_header_and_the_profile_and_leaves_no_temporary(tmp_path, tool):
    tool.set_line(*LINES["diagonal"])
    path = tmp_path / "profile.csv"
    tool.save_csv(path)
    assert path.read_text().splitlines()[0] == "distance_grid_steps,R,G,B"
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    distances, values = tool.profile()
    np.testing.assert_allclose(table, np.column_stack([distances, values]), rtol=1e-8, atol=1e-12)
    assert [entry.name for entry in tmp_path.iterdir()] == ["profile.csv"]
    with pytest.raises(OutputError):
        tool.save_csv(path)
    tool.set_data(RAMP[..., 0])
    tool.save_csv(path, overwrite=True)
    assert path.read_text().splitlines()[0] == "distance_grid_steps,value"
    np.testing.assert_allclose(np.loadtxt(path, delimiter=",", skiprows=1)[:, 1], tool.profile()[1][:, 0], rtol=1e-8)
    assert [entry.name for entry in tmp_path.iterdir()] == ["profile.csv"]


def test_data_of_another_shape_are_refused(tool):
    with pytest.raises(ValueError, match=r"\(H, W\) or \(H, W, 3\)"):
        tool.set_data(np.zeros((HEIGHT, WIDTH, 4)))


def test_each_new_profile_is_painted_once_and_fits_the_view(qtbot):
    """Once its axes have their width (labels of the same size), a new profile paints the plot once:
    pyqtgraph brought the range up to date while painting, which asked for a second paint."""
    plot = LineProfilePlot()
    qtbot.addWidget(plot)
    plot.resize(320, 160)
    plot.show()
    qtbot.waitExposed(plot)
    view = plot.plot.getViewBox()
    counter = PaintCounter(plot.findChild(pg.PlotWidget).viewport())
    rng = np.random.default_rng(4)
    for index, length in enumerate((30, 10, 40, 25)):
        distances = np.arange(length, dtype=float)
        values = 20 + 60 * rng.random((length, 3))  # labels 20 .. 80 whatever the draw
        qtbot.wait(20)
        counter.count = 0
        plot.set_profile(distances, values, f"{length} samples")
        for _ in range(5):
            QApplication.processEvents()
        assert index == 0 or counter.count == 1  # the first profile lays the axes out
        (x0, x1), (y0, y1) = view.viewRange()
        assert x0 <= 0 and x1 >= length - 1 and y0 <= values.min() and y1 >= values.max()
