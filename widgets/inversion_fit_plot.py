"""The inverse method's fit, as a person checks it: the region's measured E(r) per channel with
two-sigma error bars, the fitted model over it (log y), and the normalised residuals below."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtWidgets import QWidget

CHANNEL_PENS = ("#ff5a5a", "#5ad65a", "#6a8cff")
KEY = "dots: measured (open: not fitted)<br>lines: model &middot; bars: 2 sigma"
"""Two short lines: a plot's title holds the plot at least as wide as itself."""
EMPTY_RADIUS = 12.0
"""Radius (grid steps) the empty plot's axis reaches, that of the bundled samples' max_radius."""


class InversionFitPlot(pg.GraphicsLayoutWidget):
    """Call :meth:`show_fit` with radii (R,), measured and model (R, 3), sigma (R, 3) and the rings
    used per channel; :meth:`clear_fit` empties it."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setBackground("#151518")
        self.profile = self.addPlot(row=0, col=0)
        self.profile.setLogMode(y=True)
        self.profile.setLabel("left", "E(r)")
        self.profile.showGrid(x=True, y=True, alpha=0.15)
        self.profile.getAxis("left").enableAutoSIPrefix(False)
        # The key above the plot: inside it, the far rings of a short plot ran under the text.
        self.profile.setTitle(KEY, color="#bbbbbb", size="7pt")
        self.residuals = self.addPlot(row=1, col=0)
        self.residuals.setXLink(self.profile)
        self.residuals.setLabel("left", "resid. / sigma")
        self.residuals.setLabel("bottom", "r (grid steps)")
        self.residuals.showGrid(x=True, y=True, alpha=0.15)
        self.residuals.addLine(y=0, pen=pg.mkPen("#888888"))
        for level in (-2, 2):
            self.residuals.addLine(y=level, pen=pg.mkPen("#555555", style=pg.QtCore.Qt.PenStyle.DashLine))
        # Radii and residuals in plain numbers: an empty plot's 0..1 range read "r (grid steps)
        # (x0.001)" with ticks 200..800.
        self.residuals.getAxis("bottom").enableAutoSIPrefix(False)
        self.residuals.getAxis("left").enableAutoSIPrefix(False)
        self.ci.layout.setRowStretchFactor(0, 3)
        self.ci.layout.setRowStretchFactor(1, 2)
        self._items: list = []
        self.clear_fit()

    def clear_fit(self) -> None:
        """Remove the fit; the axes show the ranges of a typical one (r 0..EMPTY_RADIUS, E(r)
        1e-4..1, residuals -3..3) until the next."""
        for plot, item in self._items:
            plot.removeItem(item)
        self._items = []
        self.profile.setRange(xRange=(0, EMPTY_RADIUS), yRange=(-4, 0), padding=0.02)  # log10 of E(r)
        self.residuals.setYRange(-3, 3, padding=0.02)

    def show_fit(self, radii, measured, model, sigma, used) -> None:
        """Points for the rings fitted (open circles beyond them), error bars of two sigma, model lines."""
        self.clear_fit()
        radii = np.asarray(radii, np.float64)
        for c, (name, colour) in enumerate(zip("RGB", CHANNEL_PENS)):
            values, fitted, spread = measured[:, c], model[:, c], sigma[:, c]
            good = np.isfinite(values) & (values > 0)
            inside = good & (np.arange(len(radii)) < used[c])
            outside = good & ~inside
            # Error bars in log space: log10(E +- 2 sigma), clipped above zero.
            low = np.log10(np.clip(values - 2 * spread, values * 1e-3, None))
            high = np.log10(values + 2 * spread)
            bars = pg.ErrorBarItem(x=radii[good], y=np.log10(values[good]), top=(high - np.log10(values))[good],
                                   bottom=(np.log10(values) - low)[good], pen=pg.mkPen(colour, width=1), beam=0.15)
            self.profile.addItem(bars)
            points = self.profile.plot(radii[inside], values[inside], pen=None, symbol="o", symbolSize=6,
                                       symbolBrush=colour, symbolPen=None)
            beyond = self.profile.plot(radii[outside], values[outside], pen=None, symbol="o", symbolSize=6,
                                       symbolBrush=None, symbolPen=colour)
            shown = np.isfinite(fitted) & (fitted > 0)
            line = self.profile.plot(radii[shown], fitted[shown], pen=pg.mkPen(colour, width=2), name=f"{name} model")
            with np.errstate(invalid="ignore", divide="ignore"):
                normalised = (values - fitted) / spread
            keep = inside & np.isfinite(normalised)
            marks = self.residuals.plot(radii[keep] + (c - 1) * 0.12, normalised[keep], pen=None, symbol="o",
                                        symbolSize=6, symbolBrush=colour, symbolPen=None)
            self._items += [(self.profile, bars), (self.profile, points), (self.profile, beyond),
                            (self.profile, line), (self.residuals, marks)]
        for plot in (self.profile, self.residuals):
            plot.enableAutoRange()
