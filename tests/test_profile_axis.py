"""Profile axis labels: readable log-y values, one level of them, a title that agrees with them,
and the radius in grid steps or mm."""

import math
import re

import numpy as np
import pytest

pytest.importorskip("PySide6")
from axis_labels import drawn_text_specs  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402
from qt_paints import PaintCounter  # noqa: E402
from reference import random_impulses, write_dataset  # noqa: E402
from ringlight.widgets.profile_plot import BAND_SE, ProfilePlot, ValueAxis  # noqa: E402


@pytest.mark.parametrize("low, high", [(4e4, 9e4), (1e-3, 1e3), (2.5e2, 3.1e2)])
def test_log_labels_are_distinct_values_inside_the_range(qtbot, low, high):
    axis = ValueAxis("left")
    axis.setLogMode(False, True)
    levels = axis.tickValues(math.log10(low), math.log10(high), 300)
    assert len(levels) == 1  # one labelled level: no minor labels on top of major ones
    spacing, values = levels[0]
    labels = axis.tickStrings(values, 1.0, spacing)
    numbers = [float(label) for label in labels]
    assert len(set(labels)) == len(labels) >= 2
    assert all(low <= number <= high for number in numbers)
    # Each label is its tick's value to 3 significant digits (pyqtgraph's own read "10^4" for 4e4..9e4).
    np.testing.assert_allclose(numbers, [float(f"{10 ** v:.3g}") for v in values])


RADII = np.arange(11.0)
# E(r) of a bright point falling off over four decades, all channels alike: values 0.12 .. 1.2e-5.
RING = np.repeat((0.12 * 10.0 ** (-0.4 * RADII))[:, None], 3, axis=1)


def drawn_labels(axis) -> list[tuple[float, str]]:
    """(value at the tick, label) of every tick label ``axis`` draws now, the value read from the
    tick's place on the linked view (10 ** it on a log axis)."""
    texts = drawn_text_specs(axis)
    view = axis.linkedView()
    vertical = axis.orientation in ("left", "right")
    labels = []
    for rect, _, text in texts:
        point = view.mapSceneToView(axis.mapToScene(rect.center()))  # labels are centred on their tick
        value = point.y() if vertical else point.x()
        labels.append((10.0 ** value if axis.logMode else value, text))
    return labels


def title_factor(axis) -> float:
    """The factor pyqtgraph's title announces ("radiance (x0.001)": 0.001), 1 when none."""
    found = re.search(r"\(x([0-9.e+-]+)\)", axis.label.toPlainText())
    return float(found.group(1)) if found else 1.0


@pytest.fixture
def plot(qtbot):
    plot = ProfilePlot()
    qtbot.addWidget(plot)
    plot.resize(420, 560)
    plot.set_profiles(RADII, RING, RING - np.vstack([RING[1:], RING[-1:]]))
    plot.show()
    qtbot.waitExposed(plot)
    return plot


@pytest.mark.parametrize("log_y", [False, True])
def test_value_labels_times_the_titles_factor_are_the_values_at_their_ticks(qtbot, plot, log_y):
    plot.set_log_y(log_y)
    plot.ring_plot.vb.autoRange()
    qtbot.wait(50)
    axis = plot.ring_plot.getAxis("left")
    labels = drawn_labels(axis)
    assert len(labels) >= 2
    factor = title_factor(axis)
    # Linear: the maximum 0.12 gets pyqtgraph's "(x0.001)" and labels 0..120; log: no factor, since
    # the labels are the values (with "(x0.001)" above "0.1" every value read 1000x too small).
    assert factor == (1.0 if log_y else 0.001)
    if log_y:  # the view ends near the top value 0.12 (no band yet: an empty band's y = 0 stretched it to 1)
        assert 10.0 ** axis.range[1] < 0.5
    for value, text in labels:
        assert float(text) * factor == pytest.approx(value, rel=5e-3, abs=1e-9 if not log_y else 0)


def test_the_radius_axis_reads_mm_with_a_pitch_and_grid_steps_without(qtbot, plot):
    axis = plot.transient_plot.getAxis("bottom")
    for pitch_mm, unit, factor in ((0.05, "radius r (mm)", 0.05), (None, "radius r (grid steps)", 1.0)):
        plot.set_radius_unit(pitch_mm)
        qtbot.wait(50)
        labels = drawn_labels(axis)
        assert axis.label.toPlainText().strip() == unit
        assert len(labels) >= 3
        # Radius 10 grid steps at 0.05 mm per step reads 0.5 (mm); no SI prefix scales it to "500".
        for value, text in labels:
            assert float(text) == pytest.approx(value * factor, abs=1e-9)
        assert plot.ring_plot.getAxis("bottom").scale == factor
    plot.set_radius_unit(0.05)
    plot.set_radius(4.0)
    assert plot.radius_lines[0].value() == 4.0  # radii in and out stay in grid steps


def test_view_radius_in_mm_is_offered_only_when_the_pitch_is_known(qtbot, window, tmp_path):
    impulses = random_impulses(np.random.default_rng(3), 10, 10, support=4.0)
    write_dataset(tmp_path / "plain", 10, 10, impulses, max_radius=4.0)
    write_dataset(tmp_path / "pitched", 10, 10, impulses, max_radius=4.0,
                  extra={"grid": {"height": 10, "width": 10, "pitch_mm": 0.25}})
    action = window.radius_mm_action
    axis = window.profile_plot.transient_plot.getAxis("bottom")
    with qtbot.waitSignal(window.dataset_loaded, timeout=120_000):
        window.open_dataset(tmp_path / "plain")
    assert action.isCheckable() and not action.isEnabled()
    action.trigger()  # disabled: nothing happens
    assert window.profile_plot.pitch_mm is None and axis.label.toPlainText().strip() == "radius r (grid steps)"
    with qtbot.waitSignal(window.dataset_loaded, timeout=120_000):
        window.open_dataset(tmp_path / "pitched")
    assert action.isEnabled() and not action.isChecked()
    action.trigger()
    qtbot.wait(50)
    labels = dict((round(value, 6), text) for value, text in drawn_labels(axis))
    assert labels[0.4] == "0.1" and labels[2.0] == "0.5"  # r = 0.4 and 2 grid steps x 0.25 mm
    assert axis.label.toPlainText().strip() == "radius r (mm)"
    action.trigger()
    qtbot.wait(50)
    assert window.profile_plot.pitch_mm is None
    assert float(dict((round(value, 6), text) for value, text in drawn_labels(axis))[2.0]) == 2.0


def test_new_profiles_are_painted_once_and_the_view_fits_them(qtbot, plot):
    """A pick used to paint the plots twice: the auto range and the view's transform were
    brought up to date while painting, which moved every item and asked for another paint."""
    counter = PaintCounter(plot.viewport())
    rng = np.random.default_rng(5)
    for _ in range(4):
        ring = RING * rng.uniform(0.5, 3.0, RING.shape)
        se = 0.1 * ring
        qtbot.wait(20)
        counter.count = 0
        plot.set_profiles(RADII, ring, ring - 0.5 * ring, se, se)
        for _ in range(5):
            QApplication.processEvents()
        assert counter.count == 1
        # The y range holds every band edge, and pyqtgraph's auto range would leave it as it is.
        low, high = plot.ring_plot.vb.viewRange()[1]
        assert low <= (ring - BAND_SE * se).min() and (ring + BAND_SE * se).max() <= high
        assert plot.ring_plot.vb.autoRangeEnabled()[1]


def test_in_log_y_the_radius_range_holds_every_e_even_where_t_starts_later(qtbot, plot):
    ring = RING.copy()
    transient = ring - np.vstack([ring[1:], ring[-1:]])
    transient[:3] = -1.0  # T <= 0 at r = 0, 1, 2: left out in log y
    plot.set_profiles(RADII, ring, transient)
    plot.set_log_y(True)
    qtbot.wait(50)
    for axes in (plot.ring_plot, plot.transient_plot):
        low, high = axes.vb.viewRange()[0]
        assert low < 0.0 and high > 10.0  # E(0) and E(10) in view, in both linked plots
    assert plot.transient_curves[0].getData()[0].min() == 3.0
    # After a zoom, T(r)'s own "A" (auto range) button brings back the range E(r) needs.
    plot.transient_plot.vb.setXRange(4.0, 6.0)
    plot.transient_plot.autoBtn.clicked.emit(plot.transient_plot.autoBtn)
    qtbot.wait(50)
    low, high = plot.transient_plot.vb.viewRange()[0]
    assert low < 0.0 and high > 10.0
