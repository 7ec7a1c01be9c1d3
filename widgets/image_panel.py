"""An image view for grid images with a picked point and the ring drawn around it.

Pixel ``(y, x)`` of the grid covers the square ``[x, x+1) x [y, y+1)`` of the view; row 0 is at
the top. Left click or left drag picks a pixel, the wheel zooms, middle drag pans, right click
opens pyqtgraph's view menu. The panel draws RGB pixels it is given and never rescales them, so
the levels are entirely the caller's (pyqtgraph's ImageView would reset them per frame).

A display-only variant of the pixels (a denoised image) can be drawn in their place, labelled on
the image; :meth:`pixels` and :meth:`grab`, which the exports use, keep the data pixels unless the
caller allows the variant into exports. A colour bar can stand beside the image (scalar maps).
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPointF, QRectF, Qt, Signal
from PySide6.QtWidgets import QWidget

MEMBER_RGB = (255, 214, 0)
MISSING_RGB = (150, 150, 150)
_CIRCLE_POINTS = 241
TITLE_MARGIN_PX = 8
"""Room left right of the wrapped title (the text item's own padding)."""


MAX_MEMBER_ALPHA = 96
"""Opacity (0-255) of a full-weight ring member's tint: 38 %, so that 62 % of the image under the
ring shows through in every normalisation (dark Global and Manual images included)."""


def member_alpha(weights: np.ndarray) -> np.ndarray:
    """Overlay alpha (0-255) of ring members of ``weights`` in (0, 1]: 24 + 72 w (at most
    :data:`MAX_MEMBER_ALPHA`), so the image stays visible under the ring and partial
    anti-aliased weights are readable."""
    return np.round(24 + (MAX_MEMBER_ALPHA - 24) * np.clip(weights, 0, 1)).astype(np.uint8)


def scale_bar_length(target: float) -> float:
    """The round length (1, 2 or 5 times a power of ten) nearest ``target`` from below."""
    power = 10.0 ** np.floor(np.log10(target))
    return float(max(step * power for step in (1, 2, 5) if step * power <= target * (1 + 1e-9)))


class _PickingViewBox(pg.ViewBox):
    """A ViewBox whose left button picks pixels instead of panning."""

    def __init__(self, on_pick):
        super().__init__(lockAspect=True, invertY=True, enableMenu=True)
        self._on_pick = on_pick

    def mouseClickEvent(self, event):
        if event.button() == Qt.MouseButton.LeftButton:
            event.accept()
            self._on_pick(self.mapSceneToView(event.scenePos()))
        else:
            super().mouseClickEvent(event)

    def mouseDragEvent(self, event, axis=None):
        if event.button() == Qt.MouseButton.LeftButton:
            event.accept()
            self._on_pick(self.mapSceneToView(event.scenePos()))
        else:
            super().mouseDragEvent(event, axis)


class ImagePanel(pg.GraphicsView):
    """Shows (H, W, 3) uint8 RGB pixels with an optional ring overlay.

    Signals
    -------
    pixel_picked(y, x)
        A pixel was clicked or dragged over.
    pixel_hovered(y, x)
        The cursor is over pixel (y, x); (-1, -1) when it leaves the image.
    """

    pixel_picked = Signal(int, int)
    pixel_hovered = Signal(int, int)
    region_changed = Signal()

    def __init__(self, title: str = "", parent: QWidget | None = None):
        super().__init__(parent, background="#202024")
        self.view = _PickingViewBox(self._pick_at)
        self.layout_item = pg.GraphicsLayout()
        self.layout_item.setContentsMargins(0, 0, 0, 0)
        self.layout_item.addItem(self.view, 0, 0)
        self.setCentralItem(self.layout_item)
        self.colour_bar: pg.ColorBarItem | None = None
        self._colour_bar_key: tuple | None = None
        self.image_item = pg.ImageItem(axisOrder="row-major")
        self.overlay_item = pg.ImageItem(axisOrder="row-major")
        self.overlay_item.setZValue(10)
        self.circle = pg.PlotCurveItem(pen=pg.mkPen(MEMBER_RGB, width=1.5))
        self.outer_circle = pg.PlotCurveItem(pen=pg.mkPen(MEMBER_RGB, width=1, style=Qt.PenStyle.DashLine))
        self.marker = pg.ScatterPlotItem(symbol="+", size=14, pen=pg.mkPen("c", width=2), brush=None)
        for item in (self.circle, self.outer_circle, self.marker):
            item.setZValue(20)
        for item in (self.image_item, self.overlay_item, self.circle, self.outer_circle, self.marker):
            self.view.addItem(item)
        self.title = pg.TextItem(title, color="w", anchor=(0, 0))
        self.title.setParentItem(self.view)
        # Wrapped at the view's width: a long title ran on under the colour bar, cut off there.
        self.view.sigResized.connect(lambda _: self.title.setTextWidth(max(self.view.width() - TITLE_MARGIN_PX, 1)))
        self.display_label = pg.TextItem("", color="#ffd600", anchor=(0, 1), fill=pg.mkBrush(0, 0, 0, 170))
        self.display_label.setParentItem(self.view)
        self.display_label.setZValue(40)
        self.view.sigResized.connect(lambda _: self.display_label.setPos(0, self.view.height()))
        self._data_pixels: np.ndarray | None = None
        self._display_pixels: np.ndarray | None = None
        self._display_in_exports = False
        self._shape: tuple[int, int] | None = None
        self._region_mode = "all"
        self.region_roi: pg.ROI | None = None
        self._ring: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.scale_bar: pg.ScaleBar | None = None
        self.scene().sigMouseMoved.connect(self._on_mouse_moved)
        self.setMinimumSize(240, 240)

    @property
    def grid_shape(self) -> tuple[int, int] | None:
        return self._shape

    def set_title(self, text: str) -> None:
        self.title.setText(text)

    def set_scale_bar(self, pitch_mm: float | None, grid_width: int) -> None:
        """Show a scale bar in mm (bottom right) when the grid's ``pitch_mm`` is known, of a
        round length near a fifth of the grid's width; None removes it."""
        if self.scale_bar is not None:
            # Not setParentItem(None): pyqtgraph's ScaleBar re-anchors itself there and raises
            # without a parent. Removing it from the scene detaches it from the view too.
            self.scene().removeItem(self.scale_bar)
            self.scale_bar = None
        if not pitch_mm:
            return
        length_mm = scale_bar_length(grid_width * pitch_mm / 5)
        self.scale_bar = pg.ScaleBar(size=length_mm / pitch_mm, suffix="")
        self.scale_bar.text.setText(f"{length_mm:g} mm")
        self.scale_bar.setParentItem(self.view)
        self.scale_bar.anchor((1, 1), (1, 1), offset=(-12, -12))

    def set_pixels(self, pixels: np.ndarray, display: np.ndarray | None = None, label: str = "") -> None:
        """Show (H, W, 3) uint8 RGB ``pixels``, or in their place ``display`` (same shape), a
        display-only variant that is labelled ``label`` on the image; a new grid size resets
        the zoom."""
        shape = pixels.shape[:2]
        self._data_pixels, self._display_pixels = pixels, display
        self.display_label.setText(label if display is not None else "")
        self.display_label.setVisible(display is not None)
        # levels None: pyqtgraph wraps uint8 pixels in a QImage as they are; levels (0, 255) sent
        # them through its general rescaling path (2 ms a scrub step at 800 x 800).
        self.image_item.setImage(pixels if display is None else display, autoLevels=False, levels=None)
        if shape != self._shape:
            self._shape = shape
            self.clear_ring()
            self.view.setRange(xRange=(0, shape[1]), yRange=(0, shape[0]), padding=0.02)
            if self._region_mode != "all":
                self.set_region_mode(self._region_mode)

    def clear_image(self) -> None:
        """Show nothing (no pixels, ring or title), as before the first image."""
        self.image_item.clear()
        self._data_pixels = self._display_pixels = None
        self._shape = None
        self.display_label.hide()
        self.clear_ring()
        self.set_title("")

    def set_region_mode(self, mode: str) -> None:
        """``"all"`` (no ROI), ``"rectangle"`` or ``"polygon"``: an editable ROI on the image,
        initially the middle half of the grid; edits emit ``region_changed``."""
        if self.region_roi is not None:
            self.view.removeItem(self.region_roi)
            _delete_menus(self.region_roi)
            self.region_roi = None
        self._region_mode = mode
        if mode != "all" and self._shape is not None:
            height, width = self._shape
            pen = pg.mkPen("#00e5ff", width=2)
            if mode == "rectangle":
                self.region_roi = pg.RectROI([width / 4, height / 4], [width / 2, height / 2], pen=pen,
                                             snapSize=1.0, translateSnap=True, scaleSnap=True)
            else:
                corners = [[width / 4, height / 4], [3 * width / 4, height / 4], [width / 2, 3 * height / 4]]
                self.region_roi = pg.PolyLineROI(corners, closed=True, pen=pen)
            self.region_roi.setZValue(30)
            self.region_roi.sigRegionChangeFinished.connect(lambda _: self.region_changed.emit())
            self.view.addItem(self.region_roi)
        self.region_changed.emit()

    def set_rectangle(self, y0: int, x0: int, y1: int, x1: int) -> None:
        """Place the rectangle ROI (rectangle mode) without emitting ``region_changed``."""
        if self.region_roi is not None and self._region_mode == "rectangle":
            self.region_roi.setPos((x0, y0), finish=False)
            self.region_roi.setSize((x1 - x0, y1 - y0), finish=False)

    def region_geometry(self) -> tuple[str, object]:
        """``("all", None)``, ``("rectangle", (y0, x0, y1, x1))`` clipped to the grid (end
        exclusive), or ``("polygon", (m, 2) [y, x] vertices)`` in view coordinates."""
        if self.region_roi is None or self._shape is None:
            return ("all", None)
        if self._region_mode == "rectangle":
            position, size = self.region_roi.pos(), self.region_roi.size()
            x0, y0 = int(round(position.x())), int(round(position.y()))
            x1, y1 = int(round(position.x() + size.x())), int(round(position.y() + size.y()))
            height, width = self._shape
            return ("rectangle", (max(y0, 0), max(x0, 0), min(y1, height), min(x1, width)))
        points = [self.region_roi.mapToParent(handle["pos"]) for handle in self.region_roi.handles]
        return ("polygon", np.array([[point.y(), point.x()] for point in points]))

    def set_display_in_exports(self, allowed: bool) -> None:
        """Whether :meth:`pixels` and :meth:`grab` (the exports) include a display-only variant."""
        self._display_in_exports = bool(allowed)

    def pixels(self) -> np.ndarray | None:
        """The (H, W, 3) uint8 RGB pixels for exports: those shown, except a display-only variant
        unless :meth:`set_display_in_exports` allowed it."""
        if self._display_pixels is not None and self._display_in_exports:
            return self._display_pixels
        return self._data_pixels

    def shown_pixels(self) -> np.ndarray | None:
        """The RGB pixels drawn now (a display-only variant when one is on)."""
        return self.image_item.image

    def grab(self, *args):
        """The panel as drawn (QPixmap), but drawing the data pixels, without the variant's
        label, while a display-only variant is on and not allowed into exports."""
        if self._display_pixels is None or self._display_in_exports:
            return super().grab(*args)
        self.image_item.setImage(self._data_pixels, autoLevels=False, levels=None)
        self.display_label.hide()
        try:
            return super().grab(*args)
        finally:
            self.image_item.setImage(self._display_pixels, autoLevels=False, levels=None)
            self.display_label.show()

    def set_colour_bar(self, levels: tuple[float, float] | None, colormap: pg.ColorMap | None = None,
                       label: str = "") -> None:
        """Show a colour bar of ``colormap`` over ``levels`` right of the image, titled ``label``;
        None removes it. The bar is a legend only: the caller colours the pixels alike."""
        key = None if levels is None else (levels, colormap.name, label)
        if self.colour_bar is not None and key == self._colour_bar_key:
            return
        self._colour_bar_key = key
        if self.colour_bar is not None:
            self.layout_item.removeItem(self.colour_bar)
            self.colour_bar = None
        if levels is not None:
            self.colour_bar = pg.ColorBarItem(values=levels, colorMap=colormap, label=label,
                                              interactive=False, width=14)
            # Room above and below for the end ticks' labels, which the panel's edge cut in half.
            self.colour_bar.setContentsMargins(0, 10, 0, 10)
            # The labels' own width: in the 45 px pyqtgraph fixes, labels such as 0.03215 (a nearly
            # uniform map of mu_a) did not fit, and pyqtgraph drew none of them.
            self.colour_bar.axis.setWidth(None)
            self.layout_item.addItem(self.colour_bar, 0, 1)

    def show_ring(self, center: tuple[int, int], positions: np.ndarray, weights: np.ndarray,
                  missing: np.ndarray, radius: float, outer_radius: float | None = None) -> None:
        """Mark ``center = (y, x)`` and draw the ring: the circle of ``radius`` (and a dashed one of
        ``outer_radius``), and each member pixel ``positions[i] = (y, x)`` tinted with alpha
        :func:`member_alpha` of ``weights[i]``; members flagged in ``missing`` (lit in no frame,
        so not counted) are drawn grey."""
        if self._shape is None:
            return
        positions = np.asarray(positions, np.int64).reshape(-1, 2)
        colours = np.where(np.asarray(missing, bool)[:, None], MISSING_RGB, MEMBER_RGB).astype(np.uint8)
        self._ring = (positions, colours, member_alpha(np.asarray(weights)))
        # Only the ring's bounding box is drawn (an image placed there): a click on a large grid
        # then costs the ring's size, not the grid's (a 1024 x 1024 overlay was 4 MB a click).
        if len(positions):
            (y0, x0), (y1, x1) = positions.min(axis=0), positions.max(axis=0) + 1
            box = np.zeros((y1 - y0, x1 - x0, 4), np.uint8)
            box[positions[:, 0] - y0, positions[:, 1] - x0, :3] = colours
            box[positions[:, 0] - y0, positions[:, 1] - x0, 3] = self._ring[2]
            self.overlay_item.setImage(box, autoLevels=False, levels=None)
            self.overlay_item.setRect(QRectF(float(x0), float(y0), float(x1 - x0), float(y1 - y0)))
        else:
            self.overlay_item.clear()
        cy, cx = center[0] + 0.5, center[1] + 0.5
        self.marker.setData([cx], [cy])
        self.circle.setData(*_circle(cx, cy, radius))
        if outer_radius is None:
            self.outer_circle.setData([], [])
        else:
            self.outer_circle.setData(*_circle(cx, cy, outer_radius))

    def ring_overlay(self) -> np.ndarray:
        """(H, W, 4) uint8 RGBA overlay drawn now over the whole grid (alpha 0 off the ring);
        (0, 0, 4) without a ring."""
        if self._ring is None or self._shape is None:
            return np.zeros((0, 0, 4), np.uint8)
        positions, colours, alpha = self._ring
        overlay = np.zeros((*self._shape, 4), np.uint8)
        overlay[positions[:, 0], positions[:, 1], :3] = colours
        overlay[positions[:, 0], positions[:, 1], 3] = alpha
        return overlay

    def clear_ring(self) -> None:
        self._ring = None
        self.overlay_item.clear()
        self.marker.setData([], [])
        self.circle.setData([], [])
        self.outer_circle.setData([], [])

    def pixel_at_scene(self, scene_position: QPointF) -> tuple[int, int] | None:
        """Grid pixel under a scene position, or None outside the image."""
        point = self.view.mapSceneToView(scene_position)
        return self._pixel_at(point)

    def _pixel_at(self, point: QPointF) -> tuple[int, int] | None:
        if self._shape is None:
            return None
        y, x = int(np.floor(point.y())), int(np.floor(point.x()))
        if 0 <= y < self._shape[0] and 0 <= x < self._shape[1]:
            return (y, x)
        return None

    def _pick_at(self, point: QPointF) -> None:
        pixel = self._pixel_at(point)
        if pixel is not None:
            self.pixel_picked.emit(*pixel)

    def _on_mouse_moved(self, scene_position: QPointF) -> None:
        pixel = self.pixel_at_scene(scene_position) if self.view.sceneBoundingRect().contains(scene_position) else None
        self.pixel_hovered.emit(*(pixel if pixel is not None else (-1, -1)))


def _circle(cx: float, cy: float, radius: float) -> tuple[np.ndarray, np.ndarray]:
    angle = np.linspace(0, 2 * np.pi, _CIRCLE_POINTS)
    return cx + radius * np.cos(angle), cy + radius * np.sin(angle)


def _delete_menus(roi: pg.ROI) -> None:
    """Delete the QMenus of a removed ``roi`` (its own, once shown, and its handles') at the event
    loop's next turn.

    pyqtgraph builds a parentless QMenu for every handle: a top-level widget owned by a Python
    object in reference cycles (ROI <-> handle), which the cyclic garbage collector frees at
    whatever allocation it runs in, once while ``QApplication.topLevelWidgets()`` converted its
    C++ list to Python: the menu was deleted under it (a SIGSEGV in issue 39's GUI walk, right
    after Region went back to "All pixels"). ``deleteLater`` deletes them between events instead,
    where no such list is being built; the collector then frees only Python objects.
    """
    for item in (roi, *roi.getHandles()):
        menu = getattr(item, "menu", None)
        if menu is not None:
            menu.deleteLater()
