"""A histogram of the shown image's values with the display levels as a draggable region.

Dragging the region's edges sets manual levels (pyqtgraph's own ``LinearRegionItem`` over a
step-mode histogram curve); in the other normalisations the region follows the levels in use.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QSize, Signal
from PySide6.QtWidgets import QWidget
from ringlight.core.colour.display import value_histogram

from .view_settling import settle


class LevelsHistogram(pg.PlotWidget):
    """Signals: ``levels_dragged(low, high)`` when the user drags the levels region."""

    levels_dragged = Signal(float, float)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent, background="#151518")
        self.setMaximumHeight(110)
        self.setMinimumHeight(80)
        self.hideAxis("left")
        self.getAxis("bottom").enableAutoSIPrefix(False)
        self.setMouseEnabled(x=False, y=False)
        self.setMenuEnabled(False)
        self.curve = self.plot([0, 1], [0], stepMode="center", fillLevel=0, brush=(120, 120, 140, 160),
                               pen=pg.mkPen("#aaaaaa"))
        self.region = pg.LinearRegionItem((0.0, 1.0), brush=(255, 214, 0, 40))
        self.region.setZValue(10)
        self.region.sigRegionChangeFinished.connect(self._on_dragged)
        self.addItem(self.region)
        self._updating = False

    def sizeHint(self) -> QSize:
        return QSize(220, 100)  # the dock's width comes from the controls above, not from this plot

    def set_image(self, image: np.ndarray | None, levels: tuple[float, float], scale: float = 1.0,
                  histogram: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Show the histogram of ``image`` times ``scale`` (the exposure, applied to the bin edges
        rather than to a copy of the image) and ``levels`` (linear values) as the region;
        ``histogram`` is ``value_histogram(image)`` when the caller has it already."""
        if histogram is None:
            histogram = value_histogram(image) if image is not None else (np.zeros(0), np.zeros(0))
        edges, counts = histogram
        edges = edges * scale
        if len(counts):
            # log(1 + count): the few bright values of a transient would otherwise be invisible.
            self.curve.setData(edges, np.log1p(counts))
            low, high = min(edges[0], levels[0]), max(edges[-1], levels[1])
            self.setXRange(low, high, padding=0.02)
        self._updating = True
        self.region.setRegion(levels)
        self._updating = False
        settle(self.getPlotItem().vb)  # one paint per shown image (a scrub step painted it twice)

    def _on_dragged(self) -> None:
        if not self._updating:
            low, high = self.region.getRegion()
            self.levels_dragged.emit(float(low), float(high))
