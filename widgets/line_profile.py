"""A line-profile tool for an :class:`~ringlight.widgets.image_panel.ImagePanel`: a draggable line
on the image and a plot of the values sampled along it.

Coordinates are the panel's grid coordinates ``(y, x)``: pixel ``(i, j)`` covers
``[j, j+1) x [i, i+1)``, so its value belongs to its centre ``(i + 0.5, j + 0.5)``. Distances are
in grid steps.

The samples are bilinear between pixel centres (:func:`line_samples`). pyqtgraph's own
``LineSegmentROI.getArrayRegion`` is not used for them: it reads a row-major image transposed, puts
pixel values at the pixel corners (half a pixel off the line as drawn), stops up to two samples
short of the second handle, reads 0 outside the image, and its interpolation turns a sample NaN
when a neighbour of weight 0 is NaN (ring stacks are NaN where a ring has no point).
"""

from __future__ import annotations

import os

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QObject, QPointF, Signal
from PySide6.QtWidgets import QVBoxLayout, QWidget

from ringlight.core.atomic import atomic_file
from ringlight.widgets.image_panel import ImagePanel
from ringlight.widgets.profile_plot import CHANNEL_PENS
from ringlight.widgets.view_settling import settle

LINE_RGB = (255, 64, 255)
"""The line's colour: apart from the ring (yellow) and the region (cyan) on the same image."""
SCALAR_PEN = "#e0e0e0"
DISTANCE_LABEL = "distance along the line (grid steps)"


def line_samples(image: np.ndarray, start: tuple[float, float],
                 end: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``image`` along the segment from ``start`` to ``end``.

    Parameters
    ----------
    image
        (H, W) or (H, W, C) values of the grid pixels, row 0 at the top.
    start, end
        ``(y, x)`` grid coordinates of the segment's ends.

    Returns
    -------
    distances
        (N,) float64 grid steps from ``start``: N = ceil(length) + 1 points evenly spaced from 0
        to the segment's length, so that no step exceeds one grid step and both ends are sampled.
    values
        (N, C) float64 (C = 1 for an (H, W) image): bilinear interpolation between the centres
        of the four pixels around each point; within the image's outer half pixel the edge
        pixels' values; NaN outside the image, or where a pixel of weight > 0 is NaN.

    Examples
    --------
    >>> image = np.array([[0.0, 10.0], [20.0, 30.0]])
    >>> distances, values = line_samples(image, (0.5, 0.5), (1.5, 0.5))
    >>> distances.tolist(), values[:, 0].tolist()
    ([0.0, 1.0], [0.0, 20.0])
    """
    data = image.reshape(*image.shape[:2], -1)
    size = np.array(data.shape[:2])
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    length = float(np.hypot(*(end - start)))
    count = int(np.ceil(length - 1e-9)) + 1  # 1e-9: a length of 7 + rounding is 7, not 8
    fraction = np.linspace(0.0, 1.0, count)
    points = start + fraction[:, None] * (end - start)  # (N, 2) y, x
    inside = np.all((points >= 0) & (points <= size), axis=1)
    centre = np.clip(points - 0.5, 0, size - 1)  # in pixel indices; the outer half pixel clamps
    low = np.minimum(np.floor(centre).astype(np.intp), np.maximum(size - 2, 0))
    high = np.minimum(low + 1, size - 1)
    weight_high = centre - low  # (N, 2): the weight of the higher row, column
    values = np.zeros((count, data.shape[2]))
    for rows, row_weight in ((low[:, 0], 1 - weight_high[:, 0]), (high[:, 0], weight_high[:, 0])):
        for columns, column_weight in ((low[:, 1], 1 - weight_high[:, 1]), (high[:, 1], weight_high[:, 1])):
            weight = (row_weight * column_weight)[:, None]
            # A NaN or inf pixel that does not contribute (weight 0) must not turn the sample NaN.
            values += weight * np.where(weight > 0, data[rows, columns], 0.0)
    values[~inside] = np.nan
    return fraction * length, values


def default_line(shape: tuple[int, int]) -> tuple[tuple[float, float], tuple[float, float]]:
    """``(start, end)`` in ``(y, x)`` grid coordinates of the line first shown on a grid of
    ``shape = (H, W)``: horizontal through the centres of the middle row, from 20 % to 80 % of
    the width (the ends on pixel centres, so the samples are the row's pixel values)."""
    height, width = shape
    y = height // 2 + 0.5
    x0, x1 = np.floor(np.array([0.2, 0.8]) * width) + 0.5
    return (y, float(x0)), (y, float(x1))


class LineProfilePlot(QWidget):
    """Values along a line against the distance from its start: R, G, B curves (red, green,
    blue) or one curve for scalar values; NaN points are gaps."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        graphics = pg.PlotWidget()
        layout.addWidget(graphics)
        self.plot = graphics.getPlotItem()
        self.plot.setLabel("bottom", DISTANCE_LABEL)
        self.plot.setLabel("left", "value")
        self.plot.getAxis("bottom").enableAutoSIPrefix(False)
        self.rgb_curves = [self.plot.plot(pen=pen, connect="finite") for pen in CHANNEL_PENS]
        self.scalar_curve = self.plot.plot(pen=SCALAR_PEN, connect="finite")
        self.setMinimumSize(240, 140)  # under the image at the window's minimum size, not taller

    def set_profile(self, distances: np.ndarray, values: np.ndarray, title: str) -> None:
        """Plot (N, 3) RGB or (N, 1) scalar ``values`` against (N,) ``distances`` in grid steps,
        titled ``title``."""
        rgb, empty = values.shape[1] == 3, np.zeros(0)
        for channel, curve in enumerate(self.rgb_curves):
            curve.setData(distances if rgb else empty, values[:, channel] if rgb else empty)
        self.scalar_curve.setData(empty if rgb else distances, empty if rgb else values[:, 0])
        self.plot.setTitle(title)
        settle(self.plot.vb)  # one paint per profile

    def clear(self) -> None:
        """No curves and no title."""
        for curve in (*self.rgb_curves, self.scalar_curve):
            curve.setData([], [])
        self.plot.setTitle("")


class LineProfileTool(QObject):
    """A line on an :class:`ImagePanel` (a ``pg.LineSegmentROI``: drag a handle to move an end,
    the line to move both) and the profile of the data along it in :attr:`plot_widget`.

    The panel draws display pixels only; the values profiled are the caller's, given to
    :meth:`set_data` whenever the shown image changes (it keeps a reference only, so it may be
    called while the tool is off). The line is first placed by :func:`default_line` and again
    whenever the data's grid size changes.

    Signals
    -------
    profile_changed()
        The profile was sampled again (line moved, new data) or cleared (tool off, no data).
    """

    profile_changed = Signal()

    def __init__(self, panel: ImagePanel, parent: QObject | None = None):
        super().__init__(parent)
        self.panel = panel
        self.plot_widget = LineProfilePlot()
        self.roi = pg.LineSegmentROI([(0, 0), (1, 0)], pen=pg.mkPen(LINE_RGB, width=2))
        self.roi.setZValue(30)  # above the image, its overlay and the ring
        self.roi.sigRegionChanged.connect(self._resample)
        self._data: np.ndarray | None = None
        self._enabled = False
        self._line_shape: tuple[int, int] | None = None
        self._distances = np.zeros(0)
        self._values = np.zeros((0, 1))

    def set_enabled(self, enabled: bool) -> None:
        """Show the line and its profile (once there are data), or remove the line and clear
        the plot."""
        self._enabled = bool(enabled)
        self._attach()

    def set_data(self, data: np.ndarray | None) -> None:
        """Profile ``data``: (H, W, 3) linear RGB or (H, W) scalar values of the panel's grid
        (the shown image before display mapping); None: nothing to profile."""
        if data is not None and not (data.ndim == 2 or (data.ndim == 3 and data.shape[2] == 3)):
            raise ValueError(f"line profile: data must be (H, W) or (H, W, 3), not {data.shape}")
        self._data = data
        self._attach()

    def set_line(self, start: tuple[float, float], end: tuple[float, float]) -> None:
        """Put the line's ends at ``(y, x)`` grid coordinates ``start`` and ``end``."""
        image_item = self.panel.image_item
        self.roi.blockSignals(True)  # one resample below, not one per handle
        try:
            for handle, (y, x) in zip(self.roi.getHandles(), (start, end)):
                self.roi.movePoint(handle, image_item.mapToParent(QPointF(x, y)), finish=False)
        finally:
            self.roi.blockSignals(False)
        self._resample()

    def line(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``(start, end)``: the line's ends in ``(y, x)`` grid coordinates."""
        image_item = self.panel.image_item
        # Through the parent, not mapToItem: that needs the ROI on the view, which it is not while off.
        ends = [image_item.mapFromParent(self.roi.mapToParent(handle.pos())) for handle in self.roi.getHandles()]
        return (ends[0].y(), ends[0].x()), (ends[1].y(), ends[1].x())

    def profile(self) -> tuple[np.ndarray, np.ndarray]:
        """(N,) float64 distances in grid steps and (N, C) float64 values (C = 3 for RGB, 1 for
        scalar data) along the line, as :func:`line_samples`; empty while off or without data."""
        return self._distances.copy(), self._values.copy()

    def save_csv(self, path: str | os.PathLike, overwrite: bool = False) -> None:
        """Write :meth:`profile` as CSV: a header row (``distance_grid_steps,R,G,B`` or
        ``distance_grid_steps,value``), then one row per sample, NaN as ``nan``. Written
        atomically (:func:`ringlight.core.atomic.atomic_file`); an existing ``path`` raises
        :class:`~ringlight.core.atomic.OutputError` unless ``overwrite``."""
        distances, values = self.profile()
        names = ("R", "G", "B") if values.shape[1] == 3 else ("value",)
        with atomic_file(path, overwrite=overwrite) as temporary:
            np.savetxt(temporary, np.column_stack([distances, values]), fmt="%.9g", delimiter=",",
                       header=",".join(("distance_grid_steps", *names)), comments="")

    def _attach(self) -> None:
        """Show the line on the panel and sample it when on with data; else take both away."""
        view = self.panel.view
        if not self._enabled or self._data is None:
            if self.roi.scene() is not None:
                view.removeItem(self.roi)
            if len(self._distances):  # signal a real change only: set_data may come often while off
                self._distances, self._values = np.zeros(0), np.zeros((0, 1))
                self.plot_widget.clear()
                self.profile_changed.emit()
            return
        if self.roi.scene() is None:
            view.addItem(self.roi)
        shape = self._data.shape[:2]
        if shape != self._line_shape:
            self._line_shape = shape
            self.set_line(*default_line(shape))  # samples too
        else:
            self._resample()

    def _resample(self) -> None:
        if not self._enabled or self._data is None:
            return
        start, end = self.line()
        self._distances, self._values = line_samples(self._data, start, end)
        length = self._distances[-1]
        title = (f"(y {start[0]:.1f}, x {start[1]:.1f}) → (y {end[0]:.1f}, x {end[1]:.1f}), "
                 f"length {length:.1f} grid steps")
        self.plot_widget.set_profile(self._distances, self._values, title)
        self.profile_changed.emit()
