"""The empty fit plot of the inverse method labels its axes in plain numbers (issue 39: "r (grid
steps) (x0.001)" with ticks 200..800 before any fit)."""

from __future__ import annotations

import numpy as np
from ringlight.widgets.inversion_fit_plot import EMPTY_RADIUS, InversionFitPlot


def test_the_empty_fit_plot_shows_radii_in_grid_steps_without_a_prefix(qtbot):
    plot = InversionFitPlot()
    qtbot.addWidget(plot)
    plot.resize(400, 300)
    plot.show()
    axis = plot.residuals.getAxis("bottom")
    assert "0.001" not in axis.labelString() and "r (grid steps)" in axis.labelString()
    assert axis.autoSIPrefixScale == 1.0
    low, high = plot.residuals.viewRange()[0]
    assert low <= 0 < EMPTY_RADIUS <= high < EMPTY_RADIUS + 1


def test_a_fit_s_radii_set_the_range_again(qtbot):
    plot = InversionFitPlot()
    qtbot.addWidget(plot)
    radii = np.arange(0.0, 31.0)
    measured = np.exp(-radii / 5)[:, None].repeat(3, axis=1)
    plot.show_fit(radii, measured, measured, 0.01 * measured, [31, 31, 31])
    plot.profile.vb.updateAutoRange()
    low, high = plot.residuals.viewRange()[0]
    assert low <= 0 and high >= 30
