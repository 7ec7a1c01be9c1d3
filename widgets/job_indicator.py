"""A status-bar indicator for one :class:`JobSlot`: what runs, in which phase, how far, and a Cancel button."""

from __future__ import annotations

from PySide6.QtWidgets import QHBoxLayout, QLabel, QProgressBar, QSizePolicy, QToolButton, QWidget

from .jobs import JobSlot


class JobIndicator(QWidget):
    """Shows itself while ``slot`` is busy; Cancel (or Esc through the window) cancels the job."""

    def __init__(self, slot: JobSlot, parent: QWidget | None = None):
        super().__init__(parent)
        self.slot = slot
        self.label = QLabel()
        self.description = ""
        self.bar = QProgressBar()
        self.bar.setRange(0, 1000)
        self.bar.setMaximumWidth(160)
        self.bar.setTextVisible(False)
        self.cancel_button = QToolButton()
        self.cancel_button.setText("Cancel")
        self.cancel_button.clicked.connect(slot.cancel)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        for widget in (self.label, self.bar, self.cancel_button):
            layout.addWidget(widget)
        # No wider than its contents: its progress bar expands, so the status bar gave the indicator
        # a share of the room a temporary message leaves, and its label a blank stretch beside the text.
        self.setSizePolicy(QSizePolicy.Policy.Maximum, QSizePolicy.Policy.Preferred)
        slot.started.connect(self._on_started)
        slot.progress.connect(self._on_progress)
        slot.phase.connect(self._on_phase)
        slot.idle.connect(self.hide)
        self.hide()

    def _on_started(self, description: str) -> None:
        self.description = description
        self.label.setText(description)
        self.bar.setRange(0, 0)  # busy until the job reports how far it is
        self.show()

    def _on_phase(self, name: str) -> None:
        self.label.setText(f"{self.description}: {name}")

    def _on_progress(self, fraction: float) -> None:
        self.bar.setRange(0, 1000)
        self.bar.setValue(int(round(fraction * 1000)))
