"""A radius slider over a stack's radii with step buttons, play / pause, frame rate and loop, and
under the slider a strip of one SNR cell per radius (:class:`~.snr_strip.SnrStrip`)."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QDoubleSpinBox,
    QHBoxLayout,
    QLabel,
    QSlider,
    QSpinBox,
    QStyle,
    QStyleOptionSlider,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from .snr_strip import SnrStrip


class ScrubBar(QWidget):
    """Chooses an index into ``radii``.

    Keyboard: the slider's arrow / Page / Home / End keys when it has focus; the window adds
    global shortcuts through :meth:`step` and :meth:`toggle_play`.

    Signals
    -------
    index_changed(int)
        The shown radius index changed (by the user, playback or :meth:`set_index`).
    """

    index_changed = Signal(int)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self._radii = np.zeros(0)
        self.slider = QSlider(Qt.Orientation.Horizontal)
        self.slider.setPageStep(5)
        self.slider.setToolTip("Ring radius: arrows step, PgUp/PgDn jump 5, [ and ] anywhere")
        self.slider.valueChanged.connect(self._on_value_changed)
        self.radius_label = QLabel("r = -")
        self.radius_label.setMinimumWidth(90)
        self.radius_box = QDoubleSpinBox()
        self.radius_box.setDecimals(2)
        self.radius_box.setMaximumWidth(90)
        self.radius_box.setKeyboardTracking(False)  # act on Enter or focus out, not every keystroke
        self.radius_box.setToolTip("Type a radius (grid steps): the nearest radius of the stack is shown")
        self.radius_box.valueChanged.connect(lambda radius: self.set_index(self.nearest_index(radius)))
        self.back_button = QToolButton(text="◀")
        self.back_button.setToolTip("Previous radius ([)")
        self.back_button.clicked.connect(lambda: self.step(-1))
        self.forward_button = QToolButton(text="▶")
        self.forward_button.setToolTip("Next radius (])")
        self.forward_button.clicked.connect(lambda: self.step(1))
        self.play_button = QToolButton(text="Play")
        self.play_button.setCheckable(True)
        self.play_button.setToolTip("Play / pause the scrub (Space)")
        self.play_button.toggled.connect(self._on_play_toggled)
        self.fps_box = QSpinBox()
        self.fps_box.setRange(1, 60)
        self.fps_box.setValue(8)
        self.fps_box.setSuffix(" fps")
        self.fps_box.valueChanged.connect(self._on_fps_changed)
        self.loop_box = QCheckBox("Loop")
        self.loop_box.setChecked(True)
        self.timer = QTimer(self)
        self.timer.timeout.connect(self._advance)
        self.snr_strip = SnrStrip()
        track = QVBoxLayout()
        track.setSpacing(0)
        track.addWidget(self.slider)
        track.addWidget(self.snr_strip)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        for widget in (self.radius_label, self.radius_box, self.back_button):
            layout.addWidget(widget)
        layout.addLayout(track, 1)
        for widget in (self.forward_button, self.play_button, self.fps_box, self.loop_box):
            layout.addWidget(widget)
        self.set_radii(np.zeros(0))

    @property
    def radii(self) -> np.ndarray:
        return self._radii

    def index(self) -> int:
        return self.slider.value()

    def radius(self) -> float | None:
        return float(self._radii[self.index()]) if len(self._radii) else None

    def set_radii(self, radii: np.ndarray, index: int | None = None) -> None:
        """Scrub over ``radii`` (grid steps), showing ``index`` (default: the radius nearest the
        current one)."""
        previous = self.radius()
        self._radii = np.asarray(radii, np.float64)
        if index is None:
            index = self.nearest_index(previous) if previous is not None else 0
        self.slider.blockSignals(True)
        self.slider.setRange(0, max(len(self._radii) - 1, 0))
        self.slider.setValue(index)
        self.slider.blockSignals(False)
        self.setEnabled(len(self._radii) > 0)
        self.snr_strip.set_values(self._radii, None)
        self.snr_strip.set_poor_coverage(None)
        self.snr_strip.set_current(index)
        self._update_label()

    def nearest_index(self, radius: float) -> int:
        if not len(self._radii):
            return 0
        return int(np.argmin(np.abs(self._radii - radius)))

    def set_index(self, index: int) -> None:
        self.slider.setValue(int(np.clip(index, 0, max(len(self._radii) - 1, 0))))

    def step(self, delta: int) -> None:
        self.set_index(self.index() + delta)

    def toggle_play(self) -> None:
        self.play_button.toggle()

    def set_snr(self, snr: np.ndarray | None, description: str = "") -> None:
        """Colour the strip under the slider with (len(radii),) ``snr``, one per radius, as
        ``description`` names it (shown in the tooltip); None clears it."""
        self.snr_strip.set_values(self._radii, snr, description)
        self._align_strip()

    def set_poor_coverage(self, poor: np.ndarray | None) -> None:
        """Hatch the strip's cells of the radii where ``poor`` ((len(radii),) bool) is set: the
        dataset's lit points cover those rings poorly (:mod:`ringlight.core.rings.coverage`)."""
        self.snr_strip.set_poor_coverage(poor)
        self._align_strip()

    def set_fps(self, fps: int) -> None:
        self.fps_box.setValue(fps)

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self._align_strip()

    def _align_strip(self) -> None:
        """Inset the strip's cells by half the slider's handle, so that each lies under the
        handle's position for its radius."""
        option = QStyleOptionSlider()
        self.slider.initStyleOption(option)
        handle = self.slider.style().subControlRect(QStyle.ComplexControl.CC_Slider, option,
                                                    QStyle.SubControl.SC_SliderHandle, self.slider)
        cell = (self.slider.width() - handle.width()) / max(len(self._radii) - 1, 1)
        # Cell i centred on the handle's centre at value i: margin = half the handle - half a cell.
        self.snr_strip.set_margin(max(int(round((handle.width() - cell) / 2)), 0))

    def _on_value_changed(self, index: int) -> None:
        self._update_label()
        self.snr_strip.set_current(index)
        self.index_changed.emit(index)

    def _update_label(self) -> None:
        radius = self.radius()
        self.radius_box.blockSignals(True)
        if len(self._radii):
            self.radius_box.setRange(float(self._radii.min()), float(self._radii.max()))
        if radius is not None:
            self.radius_box.setValue(radius)
        self.radius_box.blockSignals(False)
        self.radius_label.setText("r = -" if radius is None else f"r = {radius:g}  ({self.index() + 1}/{len(self._radii)})")

    def _on_play_toggled(self, playing: bool) -> None:
        self.play_button.setText("Pause" if playing else "Play")
        if playing:
            if self.index() == len(self._radii) - 1:
                self.set_index(0)
            self.timer.start(int(round(1000 / self.fps_box.value())))
        else:
            self.timer.stop()

    def _on_fps_changed(self, fps: int) -> None:
        if self.timer.isActive():
            self.timer.start(int(round(1000 / fps)))

    def _advance(self) -> None:
        if self.index() < len(self._radii) - 1:
            self.step(1)
        elif self.loop_box.isChecked():
            self.set_index(0)
        else:
            self.play_button.setChecked(False)
