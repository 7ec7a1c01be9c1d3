"""Log-y profile labels are readable values, one level of them, never stacked or cut."""

import math

import numpy as np
import pytest

pytest.importorskip("PySide6")
from ringlight.widgets.profile_plot import ValueAxis  # noqa: E402


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
