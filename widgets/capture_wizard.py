"""The capture wizard's pages: devices, live view, dark frame, colour, correspondence, exposure and
region, plan, scan, finish (the calibration pages are in :mod:`.calibration_pages`).

Steps are listed on the left and each can be re-entered; the widget shows what it is given and
reports what the user asks for by signals (the app runs the hardware in workers).
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QListWidget,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from .calibration_pages import ColourPage, DarkFramePage, LiveViewPage
from .image_panel import ImagePanel
from .reference_calibration import ReferenceCalibrationBox

STEPS = ["1  Devices", "2  Live view", "3  Dark frame", "4  Colour", "5  Correspondence",
         "6  Region and exposure", "7  Plan", "8  Scan", "9  Finish"]
(DEVICES, LIVE_VIEW, DARK_FRAME, COLOUR, CORRESPONDENCE, REGION, PLAN, SCAN, FINISH) = range(len(STEPS))
MULTIPLEX_CHOICES = {"Off: one lattice frame per capture": 0, "Hadamard code of 7": 7,
                     "Hadamard code of 15": 15, "Hadamard code of 31": 31}


def _page(*widgets) -> QWidget:
    page = QWidget()
    layout = QVBoxLayout(page)
    for widget in widgets:
        if isinstance(widget, QHBoxLayout | QFormLayout):
            layout.addLayout(widget)
        else:
            layout.addWidget(widget)
    layout.addStretch(1)
    return page


def _label(text: str = "") -> QLabel:
    label = QLabel(text)
    label.setWordWrap(True)
    return label


class CaptureWizard(QWidget):
    """Signals
    -------
    open_requested(camera, projector, options, camera_options)
    live_requested(exposure_s), live_stop_requested()
    dark_requested(exposure_s, frames)
    chart_requested(), colour_fit_requested(corners)
    correspondence_requested()
    probe_requested(roi, max_radius)      roi = (y0, x0, y1, x1)
    scan_requested(out, resume)
    pause_requested()
    open_dataset_requested(path)
    """

    open_requested = Signal(str, str, str, str)
    correspondence_requested = Signal()
    probe_requested = Signal(tuple, float)
    scan_requested = Signal(str, bool)
    pause_requested = Signal()
    open_dataset_requested = Signal(str)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.steps = QListWidget()
        self.steps.addItems(STEPS)
        self.steps.setFixedWidth(190)
        self.pages = QStackedWidget()
        self.steps.currentRowChanged.connect(self.pages.setCurrentIndex)

        # 1 devices
        self.camera_box = QComboBox()
        self.projector_box = QComboBox()
        self.options_edit = QLineEdit("size=24x24 photons=600")
        self.options_edit.setToolTip("KEY=VALUE options for both devices, separated by spaces")
        self.open_button = QPushButton("Open devices")
        self.camera_options_edit = QLineEdit()
        self.camera_options_edit.setPlaceholderText("e.g. serial=0815-0000 pixel_format=Mono12")
        self.camera_options_edit.setToolTip("KEY=VALUE options for the camera only, separated by spaces")
        self.open_button.clicked.connect(lambda: self.open_requested.emit(
            self.camera_box.currentText(), self.projector_box.currentText(), self.options_edit.text(),
            self.camera_options_edit.text()))
        self.devices_label = _label()
        devices = QFormLayout()
        devices.addRow("Camera", self.camera_box)
        devices.addRow("Projector", self.projector_box)
        devices.addRow("Options", self.options_edit)
        devices.addRow("Camera options", self.camera_options_edit)
        self.pages.addWidget(_page(devices, self.open_button, self.devices_label))

        # 2-4 live view, dark frame, colour
        self.live_page = LiveViewPage()
        self.dark_page = DarkFramePage()
        self.colour_page = ColourPage()
        for page in (self.live_page, self.dark_page, self.colour_page):
            self.pages.addWidget(page)
        self.live_requested = self.live_page.live_requested
        self.live_stop_requested = self.live_page.stop_requested
        self.dark_requested = self.dark_page.dark_requested
        self.chart_requested = self.colour_page.chart_requested
        self.colour_fit_requested = self.colour_page.fit_requested

        # 2 correspondence
        self.correspondence_button = QPushButton("Project Gray code and decode")
        self.correspondence_button.clicked.connect(self.correspondence_requested)
        self.correspondence_label = _label("Shows OpenCV Gray code patterns, decodes the projector pixel each camera "
                                           "pixel sees and fits a homography.")
        self.mapping_view = ImagePanel("camera view: projector column seen (viridis), grey: none")
        self.mapping_view.setMinimumHeight(260)
        self.pages.addWidget(_page(self.correspondence_button, self.correspondence_label, self.mapping_view))

        # 3 region and exposure
        self.roi_boxes = [QSpinBox() for _ in range(4)]
        for box in self.roi_boxes:
            box.setRange(0, 100000)
        roi = QGridLayout()  # two rows, so that the page fits beside the step list on a small screen
        for index, (name, box) in enumerate(zip(("y0", "x0", "y1", "x1"), self.roi_boxes)):
            roi.addWidget(QLabel(name), index // 2, 2 * (index % 2))
            roi.addWidget(box, index // 2, 2 * (index % 2) + 1)
        self.radius_box = QDoubleSpinBox()
        self.radius_box.setRange(0.5, 1000)
        self.radius_box.setValue(6.0)
        self.radius_box.setSuffix(" grid steps")
        self.probe_button = QPushButton("Probe exposures")
        self.probe_button.clicked.connect(lambda: self.probe_requested.emit(self.roi(), self.radius_box.value()))
        self.probe_label = _label("The region is in projector pixels (end exclusive): drag the rectangle on the "
                                  "view or type it. max_radius is the largest distance at which light is "
                                  "attributed to a lit point.")
        self.region_view = ImagePanel("projector view under white light: drag the region")
        self.region_view.setMinimumHeight(240)
        self.region_view.region_changed.connect(self._on_region_dragged)
        for box in self.roi_boxes:
            box.valueChanged.connect(self._on_roi_typed)
        region = QFormLayout()
        region.addRow("Region", roi)
        region.addRow("max_radius", self.radius_box)
        self.pages.addWidget(_page(region, self.region_view, self.probe_button, self.probe_label))

        # 4 plan
        self.plan_label = _label("Probe exposures first.")
        self.out_edit = QLineEdit()
        browse = QPushButton("Browse…")
        browse.clicked.connect(self._browse)
        out = QHBoxLayout()
        out.addWidget(QLabel("Output folder"))
        out.addWidget(self.out_edit, 1)
        out.addWidget(browse)
        self.multiplex_box = QComboBox()
        self.multiplex_box.addItems(list(MULTIPLEX_CHOICES))
        self.multiplex_box.setToolTip("Light several lattice frames per capture through a Hadamard S-matrix code "
                                      "and demultiplex: more signal where read noise dominates (faint light), "
                                      "less where shot noise does (see benchmarks/bench_multiplex.py)")
        coding = QFormLayout()
        coding.addRow("Multiplexing", self.multiplex_box)
        self.pages.addWidget(_page(self.plan_label, out, coding))

        # 5 scan
        self.scan_button = QPushButton("Start scan")
        self.scan_button.clicked.connect(lambda: self.scan_requested.emit(self.out_edit.text(), False))
        self.resume_button = QPushButton("Resume")
        self.resume_button.clicked.connect(lambda: self.scan_requested.emit(self.out_edit.text(), True))
        self.pause_button = QPushButton("Pause")
        self.pause_button.clicked.connect(self.pause_requested)
        buttons = QHBoxLayout()
        for button in (self.scan_button, self.pause_button, self.resume_button):
            buttons.addWidget(button)
        self.scan_bar = QProgressBar()
        self.scan_bar.setRange(0, 1000)
        self.scan_label = _label()
        self.drift_label = _label("Projector check: the light of one lit impulse is measured again during the scan.")
        self.pages.addWidget(_page(buttons, self.scan_bar, self.scan_label, self.drift_label))

        # 6 finish
        self.finish_label = _label("The dataset appears here when the scan is complete.")
        self.open_dataset_button = QPushButton("Open in the explorer")
        self.open_dataset_button.setEnabled(False)
        self.open_dataset_button.clicked.connect(lambda: self.open_dataset_requested.emit(self.out_edit.text()))
        self.reference_box = ReferenceCalibrationBox()
        self.pages.addWidget(_page(self.finish_label, self.open_dataset_button, self.reference_box))

        self.back_button = QPushButton("< Back")
        self.back_button.clicked.connect(lambda: self.go_to(self.steps.currentRow() - 1))
        self.next_button = QPushButton("Next >")
        self.next_button.clicked.connect(lambda: self.go_to(self.steps.currentRow() + 1))
        navigation = QHBoxLayout()
        navigation.addStretch(1)
        navigation.addWidget(self.back_button)
        navigation.addWidget(self.next_button)
        right = QVBoxLayout()
        right.addWidget(self.pages, 1)
        right.addLayout(navigation)
        layout = QHBoxLayout(self)
        layout.addWidget(self.steps)
        layout.addLayout(right, 1)
        self.steps.currentRowChanged.connect(self._update_navigation)
        self.steps.setCurrentRow(0)
        self.set_scan_state("idle")

    def set_devices(self, cameras: list[str], projectors: list[str], failures: list[str]) -> None:
        self.camera_box.clear()
        self.camera_box.addItems(cameras)
        self.projector_box.clear()
        self.projector_box.addItems(projectors)
        for box in (self.camera_box, self.projector_box):
            index = box.findText("simulated")
            if index >= 0:
                box.setCurrentIndex(index)
        if failures:
            self.devices_label.setText("Skipped plugins:\n" + "\n".join(failures))

    def go_to(self, step: int) -> None:
        self.steps.setCurrentRow(max(0, min(step, len(STEPS) - 1)))

    def _update_navigation(self, step: int) -> None:
        self.back_button.setEnabled(step > 0)
        self.next_button.setEnabled(step < len(STEPS) - 1)

    def multiplex_order(self) -> int:
        """The chosen S-matrix order (0: no multiplexing)."""
        return MULTIPLEX_CHOICES[self.multiplex_box.currentText()]

    def roi(self) -> tuple[int, int, int, int]:
        return tuple(box.value() for box in self.roi_boxes)

    def set_roi(self, roi: tuple[int, int, int, int]) -> None:
        for box, value in zip(self.roi_boxes, roi):
            box.setValue(int(value))

    def show_mapping(self, mapping: np.ndarray) -> None:
        """Show where camera pixels look: the projector column as viridis, grey where none."""
        x = mapping[..., 1]
        seen = np.isfinite(x)
        span = np.nanmax(x) - np.nanmin(x) if seen.any() else 1.0
        scaled = np.where(seen, (x - (np.nanmin(x) if seen.any() else 0.0)) / (span or 1.0), 0.0)
        pixels = pg.colormap.get("viridis").map(scaled.ravel(), mode="byte")[:, :3].reshape(*x.shape, 3)
        pixels[~seen] = (72, 72, 80)
        self.mapping_view.set_pixels(np.ascontiguousarray(pixels, np.uint8))

    def show_projector_view(self, view: np.ndarray) -> None:
        """Show the (H, W) projector-space white view (grey, NaN dark) with the region on it."""
        finite = np.isfinite(view)
        top = np.nanpercentile(view, 99) if finite.any() else 1.0
        grey = np.clip(np.nan_to_num(view) / (top or 1.0) * 255, 0, 255).astype(np.uint8)
        roi = self.roi()
        self.region_view.set_pixels(np.ascontiguousarray(np.repeat(grey[:, :, None], 3, axis=2)))
        self.region_view.set_region_mode("rectangle")  # its default rectangle is replaced at once
        self.set_roi(roi)
        self._on_roi_typed()

    def _on_region_dragged(self) -> None:
        kind, rectangle = self.region_view.region_geometry()
        if kind == "rectangle":
            for box, value in zip(self.roi_boxes, rectangle):
                box.blockSignals(True)
                box.setValue(int(value))
                box.blockSignals(False)

    def _on_roi_typed(self, *_):
        self.region_view.set_rectangle(*self.roi())

    def set_scan_progress(self, fraction: float, text: str) -> None:
        """Show ``fraction`` of the scan done; the bar's percentage is the one the text uses."""
        self.scan_bar.setValue(int(round(fraction * 1000)))
        self.scan_bar.setFormat(f"{fraction:.0%}")
        self.scan_label.setText(text)

    def set_scan_state(self, state: str) -> None:
        """Enable the scan buttons for ``"idle"``, ``"running"`` or ``"paused"`` (only Resume then:
        a fresh start would refuse the folder holding the unfinished scan)."""
        self.scan_button.setEnabled(state == "idle")
        self.pause_button.setEnabled(state == "running")
        self.resume_button.setEnabled(state in ("idle", "paused"))

    def _browse(self) -> None:
        folder = QFileDialog.getSaveFileName(self, "Dataset folder to create", self.out_edit.text() or "capture")[0]
        if folder:
            self.out_edit.setText(folder)
