"""A colour bar's values are written beside it whatever their width: pyqtgraph's colour bar fixes
its axis at 45 px and leaves out every label that does not fit there, so a nearly uniform map of
mu_a (levels 0.03191 .. 0.03238 /mm, labels such as 0.03215) had a bar without a number."""

import numpy as np
import pytest
from axis_labels import drawn_text_specs
from PySide6.QtCore import QRectF
from ringlight.widgets.optics_panel import OpticsPanel


def drawn_labels(panel) -> list[tuple[QRectF, str]]:
    """The colour bar's tick labels as its axis draws them, each with its rectangle in the
    panel's widget coordinates."""
    axis = panel.image_panel.colour_bar.axis
    view = panel.image_panel
    return [(view.mapFromScene(axis.mapRectToScene(rect)).boundingRect(), text)
            for rect, _, text in drawn_text_specs(axis)]


@pytest.mark.parametrize("low, high", [(0.0319062, 0.0323781), (0.01, 0.05), (3.19, 3.24), (1.234e-4, 1.236e-4)])
def test_a_colour_bars_values_are_written_inside_the_panel(qtbot, low, high):
    panel = OpticsPanel()
    qtbot.addWidget(panel)
    panel.resize(400, 500)
    panel.show()
    qtbot.waitExposed(panel)
    values = np.linspace(low, high, 24 * 24).reshape(24, 24)  # its 1st and 99th percentiles are the levels
    panel.set_map(values, np.ones(values.shape, bool), "mu_a (/mm)", "mu_a R")
    levels = panel.levels
    for _ in range(3):  # the axis widens to its labels once it has laid them out
        panel.image_panel.grab()
        qtbot.wait(20)
    labels = drawn_labels(panel)
    numbers = [float(text) for _, text in labels]
    assert len(set(numbers)) >= 3, labels
    span = levels[1] - levels[0]
    assert all(levels[0] - 1e-9 * span <= number <= levels[1] + 1e-9 * span for number in numbers), (numbers, levels)
    inside = QRectF(panel.image_panel.rect())
    assert all(inside.contains(rect) for rect, _ in labels), [(rect, text) for rect, text in labels]
