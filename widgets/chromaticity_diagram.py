"""The CIE 1931 xy diagram with a chromaticity trajectory over radius, picked radii and layers.

Spectral locus, sRGB gamut and white point come from colour-science. Trajectory points are
coloured by radius (viridis, small to large); clicking one reports its radius.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import QWidget
from ringlight.core.colourspaces import colour_module

PICKS_KEY = ("dots: trajectory (dark: small r) &middot; rings: picks<br>"
             "stars: recovered &middot; squares: truth &middot; +: white")
"""Two short lines above the plot: inside it, a key covers whatever layer lies under it."""
FIT_KEY = ("stars: fitted &middot; squares: truth &middot; +: white<br>"
           "outlines: two-sigma (grey dashed: undetermined)")
_PICK_DISTANCE = 0.02
"""Largest xy distance from a trajectory point at which a click picks it."""


def spectral_locus() -> np.ndarray:
    """(n, 2) xy of the CIE 1931 2 degree observer's spectral colours, closed by the purple line."""
    colour = colour_module()
    xy = colour.XYZ_to_xy(colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].values)
    return np.vstack([xy, xy[:1]])


class ChromaticityDiagram(pg.PlotWidget):
    """Signals: ``radius_clicked(float)`` when a trajectory point is clicked."""

    radius_clicked = Signal(float)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent, background="#151518")
        colour = colour_module()
        self.setAspectLocked(True)
        self.setLabel("bottom", "x")
        self.setLabel("left", "y")
        for side in ("bottom", "left"):
            self.getAxis(side).enableAutoSIPrefix(False)
        self.showGrid(x=True, y=True, alpha=0.15)
        self.reset_view()
        locus = spectral_locus()
        self.plot(locus[:, 0], locus[:, 1], pen=pg.mkPen("#bbbbbb", width=1.5))
        srgb = colour.RGB_COLOURSPACES["sRGB"]
        gamut = np.vstack([srgb.primaries, srgb.primaries[:1]])
        self.plot(gamut[:, 0], gamut[:, 1], pen=pg.mkPen("#777777", style=Qt.PenStyle.DashLine))
        self.white = pg.ScatterPlotItem([srgb.whitepoint[0]], [srgb.whitepoint[1]], symbol="+", size=12,
                                        pen=pg.mkPen("w"), brush=None)
        self.addItem(self.white)
        self.path_line = self.plot([], [], pen=pg.mkPen("#666666", width=1))
        self.points = pg.ScatterPlotItem(size=8, pen=None)
        self.points.sigClicked.connect(self._on_points_clicked)
        self.addItem(self.points)
        self.picked = pg.ScatterPlotItem(size=16, symbol="o", pen=pg.mkPen("w", width=2), brush=None)
        self.addItem(self.picked)
        self.layers = pg.ScatterPlotItem(size=16, symbol="star", pen=pg.mkPen("k"))
        self.addItem(self.layers)
        self.truth = pg.ScatterPlotItem(size=14, symbol="s", pen=pg.mkPen("w", width=1.5))
        self.addItem(self.truth)
        self._regions: list = []
        self.set_key(PICKS_KEY)
        self.scene().sigMouseClicked.connect(self._on_scene_clicked)
        self._radii = np.zeros(0)
        self._xy = np.zeros((0, 2))

    def set_key(self, text: str) -> None:
        """Show ``text`` (Qt rich text) as the key (legend), in small type above the plot."""
        self.setTitle(text, color="#bbbbbb", size="7pt")

    def reset_view(self) -> None:
        """Show the whole diagram (the spectral locus), whatever the user zoomed to."""
        self.setRange(xRange=(0, 0.8), yRange=(0, 0.9), padding=0.02)

    def set_trajectory(self, radii: np.ndarray, xy: np.ndarray) -> None:
        """Plot (n, 2) chromaticities of (n,) radii; NaN entries are left out."""
        self._radii = np.asarray(radii, np.float64)
        self._xy = np.asarray(xy, np.float64)
        keep = np.isfinite(self._xy).all(axis=1)
        colours = pg.colormap.get("viridis").map(np.linspace(0, 1, max(len(self._radii), 1))[keep], mode="byte")
        self.points.setData(self._xy[keep, 0], self._xy[keep, 1], brush=[pg.mkBrush(*c) for c in colours],
                            data=self._radii[keep])
        self.path_line.setData(self._xy[keep, 0], self._xy[keep, 1])

    def set_picked(self, radii) -> None:
        index = [int(np.argmin(np.abs(self._radii - r))) for r in radii] if len(self._radii) else []
        xy = self._xy[index] if index else np.zeros((0, 2))
        keep = np.isfinite(xy).all(axis=1)
        self.picked.setData(xy[keep, 0], xy[keep, 1])

    def set_layers(self, layer_xy, layer_rgb8, truth_xy=None, truth_rgb8=None) -> None:
        """Recovered layers as stars and true layers as squares, filled with their swatch colours."""
        self._set_marks(self.layers, layer_xy, layer_rgb8)
        self._set_marks(self.truth, truth_xy or [], truth_rgb8 or [])

    def set_regions(self, polygons, rgb8, determined) -> None:
        """Uncertainty regions: closed (K, 2) xy polygons, outlined in each layer's colour, or grey
        and dashed where the layer is not determined (an empty list clears them)."""
        for item in self._regions:
            self.removeItem(item)
        self._regions = []
        for polygon, colour, sure in zip(polygons, rgb8, determined):
            polygon = np.asarray(polygon, np.float64).reshape(-1, 2)
            if len(polygon) < 2:
                continue
            closed = np.vstack([polygon, polygon[:1]])
            pen = pg.mkPen(colour, width=2) if sure else pg.mkPen("#8a8a8a", width=1.5, style=Qt.PenStyle.DashLine)
            item = pg.PlotCurveItem(closed[:, 0], closed[:, 1], pen=pen)
            self.addItem(item)
            self._regions.append(item)

    def show_around(self, points, margin: float = 0.04) -> None:
        """Zoom to the (K, 2) xy ``points`` (NaN ignored) with ``margin`` around them; the whole
        diagram when there are none."""
        points = np.asarray(points, np.float64).reshape(-1, 2)
        points = points[np.isfinite(points).all(axis=1)]
        if not len(points):
            self.reset_view()
            return
        low, high = points.min(axis=0) - margin, points.max(axis=0) + margin
        self.setRange(xRange=(low[0], high[0]), yRange=(low[1], high[1]), padding=0)

    def trajectory_xy(self) -> np.ndarray:
        return self._xy

    @staticmethod
    def _set_marks(item, xy, rgb8) -> None:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        keep = np.isfinite(xy).all(axis=1)
        brushes = [pg.mkBrush(*rgb) for rgb, k in zip(rgb8, keep) if k]
        item.setData(xy[keep, 0], xy[keep, 1], brush=brushes)

    def _on_points_clicked(self, _item, points, _event) -> None:
        if len(points):
            self.radius_clicked.emit(float(points[0].data()))

    def _on_scene_clicked(self, event) -> None:
        if event.isAccepted() or event.button() != Qt.MouseButton.LeftButton or not len(self._radii):
            return
        point = self.getPlotItem().vb.mapSceneToView(event.scenePos())
        distance = np.hypot(self._xy[:, 0] - point.x(), self._xy[:, 1] - point.y())
        if np.isfinite(distance).any() and np.nanmin(distance) < _PICK_DISTANCE:
            self.radius_clicked.emit(float(self._radii[int(np.nanargmin(distance))]))
