"""Plots of E(r) and T(r) at the picked pixel, with the current radius marked and noise bands.

The bands span E ± BAND_SE standard errors (and T likewise), the standard errors from the spread
of the ring members (:mod:`ringlight.core.rings.noise`), an upper bound of the noise where the
surface itself varies.

Clicking in either plot, or dragging the radius line, asks for that radius (``radius_requested``);
the window snaps it to the nearest radius of the stack. The radius axis reads grid steps, or mm
(``set_radius_unit(pitch_mm)``); radii in and out stay in grid steps.
"""

from __future__ import annotations

from math import ceil

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPointF, QSize, Qt, Signal
from PySide6.QtGui import QPainterPath, QPen, QPolygonF
from PySide6.QtWidgets import QGraphicsPathItem, QWidget

from .view_settling import settle

CHANNEL_PENS = ("#ff5a5a", "#5adc5a", "#5a8cff")
BAND_SE = 2.0
"""Half-width of the noise bands in standard errors (about 95 % for Gaussian noise)."""
LOG_BAND_FLOOR = 0.1
"""In log y, where E - BAND_SE * SE <= 0 the band's lower edge is drawn at this fraction of E."""
BAND_TIP = (f"Bands: value ± {BAND_SE:g} standard errors, from the spread of the ring members at each "
            f"radius (SE of T from both rings). The spread also holds real variation of the surface, so "
            f"there the band is an upper bound of the noise. In log y a lower edge <= 0 is drawn at "
            f"{LOG_BAND_FLOOR:g} x the value.")
POINT_LABEL_ROOM = 100
"""Least width of each plot's view box, pixels: room for the point label ("at y 123 x 456")."""


class Band(QGraphicsPathItem):
    """A translucent band between two edges over the same radii, drawn under the value curves as
    one closed polygon (upper edge forward, lower edge back) in the plot's coordinates: log10 of
    the values in log y. Hidden when empty, so that it adds nothing to the plot's auto range."""

    def __init__(self, colour: str):
        super().__init__()
        brush = pg.mkColor(colour)
        brush.setAlpha(60)
        self.setBrush(brush)
        self.setPen(QPen(Qt.PenStyle.NoPen))
        self.setZValue(-5)
        self._log_y = False

    def set_edges(self, radii: np.ndarray, low: np.ndarray, high: np.ndarray, log_y: bool) -> None:
        """Span (n,) ``low`` .. ``high`` at (n,) ``radii`` (all finite; positive in log y)."""
        self._log_y = log_y
        plotted = np.log10 if log_y else np.asarray
        polygon = QPolygonF([QPointF(float(x), float(y)) for x, y in
                             zip(np.concatenate([radii, radii[::-1]]),
                                 np.concatenate([plotted(high), plotted(low)[::-1]]))])
        path = QPainterPath()
        path.addPolygon(polygon)
        self.setPath(path)
        self.setVisible(len(radii) > 1)

    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radii, low, high) read back from the polygon drawn (values, not their log10)."""
        points = self.path().toFillPolygon()
        xy = np.array([(point.x(), point.y()) for point in points], np.float64).reshape(-1, 2)
        count = len(xy) // 2  # a closed polygon may repeat its first point at the end
        radii, high, low = xy[:count, 0], xy[:count, 1], xy[count:2 * count, 1][::-1]
        if self._log_y:
            high, low = 10.0 ** high, 10.0 ** low
        return radii, low, high


class ValueAxis(pg.AxisItem):
    """A y axis whose log-mode labels are plain values with 3 significant digits ("4e+04",
    "0.0012"): pyqtgraph's own log labels cut mantissas ("10^4.6" reads as "10^4") and, within one
    decade, label minor ticks on top of each other. One level is labelled: the decades when two or
    more are in view, else 2..9 times a decade, else evenly spaced values.

    In linear mode the title carries pyqtgraph's automatic scale ("radiance (x0.001)") and the
    labels are scaled to match; in log mode neither is (the labels are the values themselves)."""

    def getSIPrefixEnableRanges(self):
        # No ranges, no prefix: an "(x0.001)" in the title would make every log label read 1000x small.
        return () if self.logMode else super().getSIPrefixEnableRanges()

    def setLogMode(self, *args, **kwargs):
        super().setLogMode(*args, **kwargs)
        self.updateAutoSIPrefix()

    def tickStrings(self, values, scale, spacing):
        if not self.logMode:
            return super().tickStrings(values, scale, spacing)
        return [f"{10.0 ** value:.3g}" for value in values]

    def tickValues(self, minVal, maxVal, size):
        levels = super().tickValues(minVal, maxVal, size)
        if not self.logMode:
            return levels
        decades = [level for level in levels if level[0] is not None and level[0] >= 1.0 and len(level[1]) >= 2]
        if decades:
            return decades[:1]
        if levels and len(levels[-1][1]) >= 2:
            return levels[-1:]
        low, high = 10.0 ** minVal, 10.0 ** maxVal
        step = 10.0 ** np.floor(np.log10((high - low) / 2))
        values = np.arange(np.ceil(low / step) * step, high, step)
        return [(None, list(np.log10(values[values > 0])))]


class RadiusAxis(pg.AxisItem):
    """The radius axis, labelled in grid steps or, with ``setScale(pitch_mm)``, in mm: never with
    an automatic SI prefix, which pyqtgraph would apply to the labels without saying so in the
    title (0.6 mm would read "600")."""

    def getSIPrefixEnableRanges(self):
        return ()


class ProfilePlot(pg.GraphicsLayoutWidget):
    """Two stacked plots sharing the radius axis: ring light E(r) above, transient T(r) below.

    In log-y mode values <= 0 are left out (a log axis cannot show them); T(r) negatives are then
    visible in linear mode only, which the plot title says.
    """

    radius_requested = Signal(float)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        # Short titles: the dock is about 330 px wide on a 1366 px screen (the bands are in the tooltip).
        self.ring_plot = self.addPlot(row=0, col=0, title=f"E(r): ring light, band ±{BAND_SE:g} SE",
                                      axisItems={"left": ValueAxis("left"), "bottom": RadiusAxis("bottom")})
        self.transient_plot = self.addPlot(row=1, col=0, title="T(r) = E(r) - E(r+dr)",
                                           axisItems={"left": ValueAxis("left"), "bottom": RadiusAxis("bottom")})
        self.transient_plot.setXLink(self.ring_plot)
        # After pyqtgraph's own handler, which turns on both of T(r)'s auto ranges: see _set_axes.
        self.transient_plot.autoBtn.clicked.connect(self._radius_range_follows_e)
        self.ring_bands = [Band(colour) for colour in CHANNEL_PENS]
        self.transient_bands = [Band(colour) for colour in CHANNEL_PENS]
        self.ring_curves = [pg.PlotCurveItem(pen=colour) for colour in CHANNEL_PENS]
        self.transient_curves = [pg.PlotCurveItem(pen=colour) for colour in CHANNEL_PENS]
        self.model_curves = [pg.PlotCurveItem(pen=pg.mkPen(colour, width=1.5, style=Qt.PenStyle.DashLine))
                             for colour in CHANNEL_PENS]
        for plot, items in ((self.ring_plot, self.ring_bands + self.ring_curves + self.model_curves),
                            (self.transient_plot, self.transient_bands + self.transient_curves)):
            for item in items:
                plot.addItem(item)
        self.setToolTip(BAND_TIP)
        self.zero_line = pg.InfiniteLine(0, angle=0, pen=pg.mkPen("#888", style=Qt.PenStyle.DotLine))
        self.transient_plot.addItem(self.zero_line)
        self.radius_lines = []
        for plot in (self.ring_plot, self.transient_plot):
            plot.showGrid(x=False, y=False)
            plot.getAxis("left").setWidth(64)
            for side in ("left", "bottom"):
                # Major and minor ticks: a third level is never drawn at the dock's size, yet
                # pyqtgraph lays out its ticks and texts on every range change (3 ms a pick).
                plot.getAxis(side).setStyle(maxTickLevel=1, maxTextLevel=1)
            plot.vb.setMinimumWidth(POINT_LABEL_ROOM)
            # pyqtgraph's own transforms (log, FFT, derivative) would act on the axes but not on
            # curves and bands drawn in plot coordinates: the Display panel's "log y" sets log mode.
            plot.ctrl.transformGroup.setEnabled(False)
            plot.ctrl.transformGroup.setToolTip("Log y: the Display panel's \"log y\" box")
            line = pg.InfiniteLine(0, angle=90, movable=True, pen=pg.mkPen("#ffd600", width=2))
            line.hide()  # shown with the first profiles: over empty axes it marks nothing
            line.sigDragged.connect(self._on_line_dragged)
            plot.addItem(line)
            self.radius_lines.append(line)
        self.point_label = pg.TextItem("", color="#ddd", anchor=(1, 0))
        self.point_label.setParentItem(self.ring_plot.vb)
        self.ring_plot.vb.sigResized.connect(self._place_point_label)
        self.scene().sigMouseClicked.connect(self._on_clicked)
        self._log_y = False
        self._radii = np.zeros(0)
        self._ring = np.zeros((0, 3))
        self._transient = np.zeros((0, 3))
        self._ring_se = np.zeros((0, 3))
        self._transient_se = np.zeros((0, 3))
        self._pitch_mm: float | None = None
        self._model_radii = np.zeros(0)
        self._model = np.zeros((0, 3))
        self._set_axes()

    @property
    def log_y(self) -> bool:
        return self._log_y

    @property
    def pitch_mm(self) -> float | None:
        """The grid pitch the radius axis is labelled in (mm per grid step), or None: grid steps."""
        return self._pitch_mm

    def set_radius_unit(self, pitch_mm: float | None) -> None:
        """Label the radius axes in mm (grid steps x ``pitch_mm``), or in grid steps (None).

        Only the labels change: radii in and out (``set_radius``, ``radius_requested``) stay in grid steps.
        """
        self._pitch_mm = float(pitch_mm) if pitch_mm else None
        self._set_axes()

    def minimumSizeHint(self) -> QSize:
        """At least the size the plots' layout needs (titles, axes, the point label's room), so
        that a narrow dock cannot clip the plots at the right."""
        hint = super().minimumSizeHint()
        layout = self.ci.effectiveSizeHint(Qt.SizeHint.MinimumSize)
        frame = 2 * self.frameWidth()
        return hint.expandedTo(QSize(ceil(layout.width()) + frame, ceil(layout.height()) + frame))

    def set_profiles(self, radii: np.ndarray, ring: np.ndarray, transient: np.ndarray,
                     ring_se: np.ndarray | None = None, transient_se: np.ndarray | None = None) -> None:
        """Plot (n,) radii against (n, 3) E and T values (NaN points are left out), with bands
        of +- BAND_SE times their (n, 3) standard errors (None: no bands; NaN: none there)."""
        self._radii = np.asarray(radii, np.float64)
        self._ring = np.asarray(ring, np.float64)
        self._transient = np.asarray(transient, np.float64)
        blank = np.full(self._ring.shape, np.nan)
        self._ring_se = blank if ring_se is None else np.asarray(ring_se, np.float64)
        self._transient_se = blank if transient_se is None else np.asarray(transient_se, np.float64)
        for line in self.radius_lines:
            line.setVisible(len(self._radii) > 0)
        self._redraw()

    def set_model(self, radii: np.ndarray | None, model: np.ndarray | None = None) -> None:
        """Draw a fitted model's (n, 3) E over the (n,) ``radii`` on the E(r) plot, dashed in the
        channels' colours (NaN points left out); None removes it."""
        self._model_radii = np.zeros(0) if radii is None else np.asarray(radii, np.float64)
        self._model = np.zeros((0, 3)) if model is None else np.asarray(model, np.float64)
        self._redraw()

    def model_data(self) -> tuple[np.ndarray, np.ndarray]:
        """(radii, (n, 3) E) of the model drawn now, before any log transform."""
        return self._model_radii, self._model

    def set_point(self, text: str) -> None:
        """Name the point the profiles belong to (top right of the E(r) plot)."""
        self.point_label.setText(text)

    def _place_point_label(self) -> None:
        self.point_label.setPos(self.ring_plot.vb.width(), 0)

    def curve_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radii, E, T) plotted now, before any log transform."""
        return self._radii, self._ring, self._transient

    def set_radius(self, radius: float) -> None:
        for line in self.radius_lines:
            if line.value() == radius:
                continue  # moving a line, even nowhere, makes the plots compute their auto range again
            line.blockSignals(True)
            line.setValue(radius)
            line.blockSignals(False)

    def set_log_y(self, log_y: bool) -> None:
        self._log_y = bool(log_y)
        self._set_axes()
        self._redraw()

    def band_data(self) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], list]:
        """The bands drawn now: for E and for T, per channel ``(radii, lower, upper)``, read back
        from the polygons drawn (values, not their log10)."""
        return [band.edges() for band in self.ring_bands], [band.edges() for band in self.transient_bands]

    def _redraw(self) -> None:
        """Curves and bands from the data, in the plot's coordinates (log10 of values in log y:
        the items are plain PlotCurveItems and paths, cheaper to update than PlotDataItems, and
        the axes alone are in log mode), and the views settled (:mod:`.view_settling`): one
        paint per pick."""
        x = self._radii
        plotted = np.log10 if self._log_y else np.asarray
        for curves, bands, values, errors in (
                (self.ring_curves, self.ring_bands, self._ring, self._ring_se),
                (self.transient_curves, self.transient_bands, self._transient, self._transient_se)):
            for channel, (curve, band) in enumerate(zip(curves, bands)):
                y = values[:, channel] if len(values) else np.zeros(0)
                keep = np.isfinite(y) & ((y > 0) if self._log_y else True)
                curve.setData(x[keep], plotted(y[keep]))
                error = errors[:, channel] if len(errors) else np.zeros(0)
                shown = keep & np.isfinite(error)
                low, high = y - BAND_SE * error, y + BAND_SE * error
                if self._log_y:
                    low = np.where(low > 0, low, LOG_BAND_FLOOR * y)
                band.set_edges(x[shown], low[shown], high[shown], self._log_y)
        for channel, curve in enumerate(self.model_curves):
            y = self._model[:, channel] if len(self._model) else np.zeros(0)
            keep = np.isfinite(y) & ((y > 0) if self._log_y else True)
            curve.setData(self._model_radii[keep], plotted(y[keep]))
        settle(self.ring_plot.vb, self.transient_plot.vb)

    def _set_axes(self) -> None:
        for plot in (self.ring_plot, self.transient_plot):
            plot.setLogMode(False, self._log_y)  # also turns both plots' auto range back on
        self._radius_range_follows_e()
        self.ring_plot.setLabel("left", "radiance")
        self.transient_plot.setLabel("left", "radiance" + (" (T > 0 only)" if self._log_y else ""))
        for plot in (self.ring_plot, self.transient_plot):
            plot.getAxis("bottom").setScale(self._pitch_mm or 1.0)
        self.transient_plot.setLabel("bottom", "radius r (mm)" if self._pitch_mm else "radius r (grid steps)")
        self.zero_line.setVisible(not self._log_y)

    def _radius_range_follows_e(self) -> None:
        """The radius range follows E(r) alone: with two linked auto ranges the one that came last
        wins, and in log y T(r) often starts later (T <= 0 is left out), cutting off E(0)."""
        self.transient_plot.enableAutoRange(x=False)
        self.ring_plot.enableAutoRange(x=True)

    def _on_line_dragged(self, line: pg.InfiniteLine) -> None:
        self.radius_requested.emit(float(line.value()))

    def _on_clicked(self, event) -> None:
        if event.button() != Qt.MouseButton.LeftButton or event.isAccepted():
            return
        for plot in (self.ring_plot, self.transient_plot):
            if plot.vb.sceneBoundingRect().contains(event.scenePos()):
                self.radius_requested.emit(float(plot.vb.mapSceneToView(event.scenePos()).x()))
                return
