"""A strip of one coloured cell per radius under the scrub slider: a per-radius SNR summary,
hatched where the dataset's lit points cover the ring poorly."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QEvent, QRect, QSize, Qt
from PySide6.QtGui import QBrush, QColor, QPainter, QPen
from PySide6.QtWidgets import QToolTip, QWidget

from .snr_colours import SNR_LEVELS, TRUSTED_SNR, snr_colormap_name, snr_rgb


class SnrStrip(QWidget):
    """Cells for (n,) SNR values on the shared scale (:mod:`.snr_colours`), the current one
    outlined, radii of poor ring coverage hatched in red; hovering a cell shows its radius and
    numbers. ``margin`` (pixels) insets the cells on both sides so that cell i sits under the
    slider's handle at value i."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self._radii = np.zeros(0)
        self._snr = np.zeros(0)
        self._description = ""
        self._current = -1
        self._margin = 0
        self._poor = np.zeros(0, bool)
        self.setFixedHeight(10)

    def set_values(self, radii: np.ndarray, snr: np.ndarray | None, description: str = "") -> None:
        """Show ``snr[i]`` for ``radii[i]`` (grid steps); None or empty clears the strip.
        ``description`` says what the numbers are, e.g. "median SNR of T_r over the image"."""
        self._radii = np.asarray(radii, np.float64)
        self._snr = np.zeros(0) if snr is None else np.asarray(snr, np.float64)
        self._description = description
        self.update()

    def set_poor_coverage(self, poor: np.ndarray | None) -> None:
        """Hatch the cells of radii where ``poor`` ((n,) bool, one per radius) is set; None
        clears the marks."""
        self._poor = np.zeros(0, bool) if poor is None else np.asarray(poor, bool)
        self.update()

    def poor_coverage(self) -> np.ndarray:
        """(n,) bool: the radii marked for poor coverage (empty when none were given)."""
        return self._poor

    def values(self) -> np.ndarray:
        """(n,) SNR shown now (empty when cleared)."""
        return self._snr

    def set_current(self, index: int) -> None:
        self._current = int(index)
        self.update()

    def set_margin(self, margin: int) -> None:
        self._margin = int(margin)
        self.update()

    def sizeHint(self) -> QSize:
        return QSize(200, 10)

    def _count(self) -> int:
        return max(len(self._snr), len(self._poor)) if len(self._radii) else 0

    def cell_at(self, x: float) -> int | None:
        """Index of the cell under widget x coordinate ``x``, or None."""
        count = self._count()
        width = self.width() - 2 * self._margin
        if not count or width <= 0:
            return None
        index = int(np.floor((x - self._margin) / width * count))
        return index if 0 <= index < count else None

    def tooltip_text(self, index: int) -> str:
        coverage = ("\npoor ring coverage: few lit points near this radius bias the ring mean"
                    if index < len(self._poor) and self._poor[index] else "")
        if index >= len(self._snr):
            return f"r = {self._radii[index]:g}: noise not estimated yet{coverage}"
        value = self._snr[index]
        number = ("undefined (fewer than 2 ring members)" if np.isnan(value) else
                  "inf (standard error 0: the ring members agree exactly)" if np.isinf(value) else f"{value:.3g}")
        verdict = "" if np.isnan(value) else (" >= " if value >= TRUSTED_SNR else " < ") + f"{TRUSTED_SNR:g}"
        return (f"r = {self._radii[index]:g}: {self._description} {number}{verdict}\n"
                f"colour: {snr_colormap_name()} over SNR {SNR_LEVELS[0]:g}..{SNR_LEVELS[1]:g}{coverage}")

    def paintEvent(self, event) -> None:
        count = self._count()
        if not count:
            return
        painter = QPainter(self)
        width = self.width() - 2 * self._margin
        colours = snr_rgb(self._snr)
        edges = self._margin + np.round(np.arange(count + 1) * width / count).astype(int)
        hatch = QBrush(QColor("#e53935"), Qt.BrushStyle.BDiagPattern)
        for index in range(count):
            cell = QRect(edges[index], 0, max(edges[index + 1] - edges[index], 1), self.height())
            if index < len(self._snr):
                painter.fillRect(cell, QColor(*map(int, colours[index])))
            if index < len(self._poor) and self._poor[index]:
                painter.fillRect(cell, hatch)
        if 0 <= self._current < count:
            painter.setPen(QPen(QColor("#ffd600"), 2))
            painter.drawRect(QRect(edges[self._current] + 1, 1,
                                   max(edges[self._current + 1] - edges[self._current] - 2, 1), self.height() - 2))
        painter.end()

    def event(self, event) -> bool:
        if event.type() == QEvent.Type.ToolTip:
            index = self.cell_at(event.pos().x())
            if index is None:
                QToolTip.hideText()
            else:
                QToolTip.showText(event.globalPos(), self.tooltip_text(index), self)
            return True
        return super().event(event)
