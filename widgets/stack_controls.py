"""Controls for the stack to compute: radii r0..r1 in steps, transient dr, thickness, anti-aliasing."""

from __future__ import annotations

from PySide6.QtCore import QTimer, Signal
from PySide6.QtWidgets import QCheckBox, QDoubleSpinBox, QFormLayout, QLabel, QWidget
from ringlight.core.rings.stack_request import StackRequest

EDIT_DELAY_MS = 400
"""Edits are collected for this long before a recomputation is requested."""


def _spin(minimum: float, maximum: float, step: float, tooltip: str) -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setRange(minimum, maximum)
    box.setDecimals(2)
    box.setSingleStep(step)
    box.setSuffix(" grid steps")
    box.setKeyboardTracking(False)
    box.setToolTip(tooltip)
    return box


class StackControls(QWidget):
    """Edits a :class:`StackRequest`; ``request_changed`` fires once edits settle."""

    request_changed = Signal(object)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.start_box = _spin(0, 1e4, 0.5, "First ring radius r0 (grid steps)")
        self.stop_box = _spin(0, 1e4, 0.5, "Last ring radius r1 (grid steps, inclusive)")
        self.step_box = _spin(0.05, 1e3, 0.25, "Radius step between images")
        self.dr_box = _spin(0.05, 1e3, 0.25, "Transient step: T_r = E_r - E_(r+dr)")
        self.thickness_box = _spin(0.05, 1e3, 0.25, "Ring thickness w: members with r - w/2 <= |d| < r + w/2")
        self.antialias_box = QCheckBox("Anti-aliased rings")
        self.antialias_box.setToolTip("Weight each ring pixel by its area inside the annulus")
        self.reach_label = QLabel()
        self.reach_label.setWordWrap(True)
        layout = QFormLayout(self)
        layout.addRow("r0", self.start_box)
        layout.addRow("r1", self.stop_box)
        layout.addRow("step", self.step_box)
        layout.addRow("dr", self.dr_box)
        layout.addRow("thickness", self.thickness_box)
        layout.addRow(self.antialias_box)
        layout.addRow(self.reach_label)
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(EDIT_DELAY_MS)
        self._timer.timeout.connect(lambda: self.request_changed.emit(self.request()))
        for box in (self.start_box, self.stop_box, self.step_box, self.dr_box, self.thickness_box):
            box.valueChanged.connect(self._on_edited)
        self.antialias_box.toggled.connect(self._on_edited)
        self.set_request(StackRequest())

    def request(self) -> StackRequest:
        return StackRequest(
            start=self.start_box.value(), stop=self.stop_box.value(), step=self.step_box.value(),
            dr=self.dr_box.value(), thickness=self.thickness_box.value(),
            antialias=self.antialias_box.isChecked(),
        )

    def set_request(self, request: StackRequest, max_radius: float | None = None) -> None:
        """Show ``request`` without emitting; ``max_radius`` is shown as the reach limit."""
        widgets = (self.start_box, self.stop_box, self.step_box, self.dr_box, self.thickness_box, self.antialias_box)
        for widget in widgets:
            widget.blockSignals(True)
        self.start_box.setValue(request.start)
        self.stop_box.setValue(request.stop)
        self.step_box.setValue(request.step)
        self.dr_box.setValue(request.dr)
        self.thickness_box.setValue(request.thickness)
        self.antialias_box.setChecked(request.antialias)
        for widget in widgets:
            widget.blockSignals(False)
        if max_radius is not None:
            self.reach_label.setText(f"Reach limit: max_radius {max_radius:g}")

    def _on_edited(self, *_):
        self._timer.start()
