"""The ``screen`` projector backend: a frameless full-screen window on a chosen screen.

Patterns are drawn in physical pixels: the window's logical size times its devicePixelRatio is
the projector size, and each pattern is a QImage of that size with the same device pixel ratio,
so Qt's scaling never resamples it. The window is moved to its screen (``setScreen``) before
``showFullScreen``. Calls from worker threads (a scan) are forwarded to the GUI thread and wait
until the pattern is on screen.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QObject, Qt, QThread, Signal, Slot
from PySide6.QtGui import QGuiApplication, QImage, QPainter
from PySide6.QtWidgets import QApplication, QWidget
from ringlight.core.capture.hardware import HardwareError, HardwarePlugin


class _PatternWindow(QWidget):
    def __init__(self):
        super().__init__(None, Qt.WindowType.FramelessWindowHint | Qt.WindowType.WindowStaysOnTopHint)
        self.image: QImage | None = None
        self.setCursor(Qt.CursorShape.BlankCursor)

    def paintEvent(self, event) -> None:
        painter = QPainter(self)
        painter.fillRect(self.rect(), Qt.GlobalColor.black)
        if self.image is not None:
            painter.drawImage(0, 0, self.image)
        painter.end()


class ScreenProjector(QObject):
    """``screen``: index into QGuiApplication.screens() (a string, as typed); ``settle``: seconds."""

    _show_requested = Signal(object)

    def __init__(self, screen: str = "1", settle: str = "0.1"):
        super().__init__()
        try:
            self.screen_index = int(screen)
            self.settle_time = float(settle)
        except ValueError:
            raise HardwareError(f"screen projector: screen must be an integer and settle a number, got {screen!r}, {settle!r}") from None
        self.window: _PatternWindow | None = None
        self._size = (0, 0)
        self._show_requested.connect(self._apply, Qt.ConnectionType.BlockingQueuedConnection)

    def open(self) -> None:
        if QApplication.instance() is None:
            raise HardwareError("screen projector: needs the ringlight window (a Qt application)")
        screens = QGuiApplication.screens()
        if not 0 <= self.screen_index < len(screens):
            raise HardwareError(f"screen projector: no screen {self.screen_index}; there are {len(screens)} (0..{len(screens) - 1})")
        screen = screens[self.screen_index]
        ratio = screen.devicePixelRatio()
        geometry = screen.geometry()
        self._size = (int(round(geometry.height() * ratio)), int(round(geometry.width() * ratio)))
        self.window = _PatternWindow()
        self.window.setScreen(screen)
        self.window.setGeometry(geometry)
        self.window.showFullScreen()

    def close(self) -> None:
        if self.window is not None:
            self.window.close()
            self.window = None

    @property
    def size(self) -> tuple[int, int]:
        return self._size

    def show(self, pattern: np.ndarray) -> None:
        pattern = np.asarray(pattern)
        if pattern.shape != self._size:
            raise HardwareError(f"screen projector: pattern {pattern.shape} is not the screen's {self._size}")
        grey = np.ascontiguousarray(np.clip(np.round(pattern * 255), 0, 255).astype(np.uint8))
        if QThread.currentThread() is self.thread():
            self._apply(grey)
        else:
            self._show_requested.emit(grey)

    def show_black(self) -> None:
        self.show(np.zeros(self._size, np.float32))

    def show_white(self) -> None:
        self.show(np.ones(self._size, np.float32))

    @Slot(object)
    def _apply(self, grey: np.ndarray) -> None:
        if self.window is None:
            return
        image = QImage(grey.data, grey.shape[1], grey.shape[0], grey.strides[0], QImage.Format.Format_Grayscale8).copy()
        image.setDevicePixelRatio(self.window.devicePixelRatioF())
        self.window.image = image
        self.window.repaint()


PLUGIN = HardwarePlugin(
    name="screen",
    projectors={"screen": lambda screen="1", settle="0.1": ScreenProjector(screen, settle)},
    description="a full-screen window on a second display (options: screen, settle)",
)
