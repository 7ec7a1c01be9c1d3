"""The capture wizard's calibration pages: live view, dark frame and colour (ColorChecker).

Each page shows what it is given (``show_...`` methods, plain numpy data and core results) and
reports what the user asks for by signals; the Capture tab runs the camera in workers.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from .image_panel import ImagePanel

CORNER_NAMES = ("1 dark skin (top left)", "6 bluish green (top right)", "19 white (bottom left)",
                "24 black (bottom right)")


def _label(text: str = "") -> QLabel:
    label = QLabel(text)
    label.setWordWrap(True)
    return label


def _exposure_box(milliseconds: float) -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setDecimals(3)
    box.setRange(0.001, 100000.0)
    box.setValue(milliseconds)
    box.setSuffix(" ms")
    return box


class LiveViewPage(QWidget):
    """Streamed camera frames with saturated pixels marked and a histogram of raw values.

    Signals: ``live_requested(exposure_s)``, ``stop_requested()``.
    """

    live_requested = Signal(float)
    stop_requested = Signal()

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.exposure_box = _exposure_box(10.0)
        self.start_button = QPushButton("Start live view")
        self.start_button.clicked.connect(lambda: self.live_requested.emit(self.exposure_box.value() / 1000))
        self.stop_button = QPushButton("Stop")
        self.stop_button.clicked.connect(self.stop_requested)
        self.view = ImagePanel("camera, live (saturated pixels in red)")
        self.histogram = pg.PlotWidget(background="#202024")
        self.histogram.setLabel("bottom", "raw counts")
        self.histogram.setLabel("left", "log10 samples")
        self.histogram.setMaximumHeight(150)
        # Added with the first frame: an empty step curve cannot be drawn.
        self.histogram_curve = pg.PlotCurveItem(fillLevel=0, brush=(120, 160, 255, 120), pen=pg.mkPen("#78a0ff"))
        self.histogram.setYRange(0, 1)
        self.status = _label("Shows the camera at the exposure below, a few frames per second.")
        controls = QHBoxLayout()
        controls.addWidget(QLabel("Exposure"))
        controls.addWidget(self.exposure_box)
        controls.addWidget(self.start_button)
        controls.addWidget(self.stop_button)
        controls.addStretch(1)
        layout = QVBoxLayout(self)
        layout.addLayout(controls)
        layout.addWidget(self.view, 1)
        layout.addWidget(self.histogram)
        layout.addWidget(self.status)
        self.set_running(False)

    def set_running(self, running: bool) -> None:
        self.start_button.setEnabled(not running)
        self.stop_button.setEnabled(running)

    def show_frame(self, live) -> None:
        """Show a :class:`~ringlight.core.capture.live_view.LiveFrame`."""
        self.view.set_pixels(live.pixels)
        # log10(1 + count): a bin of one sample stands out from an empty one, a full bin does not hide it.
        self.histogram_curve.setData(live.edges, np.log10(1.0 + live.histogram), stepMode="center")
        self.histogram.setYRange(0, max(1.0, float(np.log10(1.0 + live.histogram.max()))))
        if self.histogram_curve.getViewBox() is None:
            self.histogram.addItem(self.histogram_curve)
        self.status.setText(f"Exposure {live.exposure * 1000:.3g} ms: peak {live.peak:.0f} counts above black, "
                            f"{live.saturated_fraction:.2%} of pixels saturated.")


class DarkFramePage(QWidget):
    """Averages N frames with the projector black; shows the mean and the noise.

    Signal: ``dark_requested(exposure_s, frames)``.
    """

    dark_requested = Signal(float, int)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.exposure_box = _exposure_box(10.0)
        self.frames_box = QSpinBox()
        self.frames_box.setRange(2, 1000)
        self.frames_box.setValue(16)
        self.capture_button = QPushButton("Capture dark frames")
        self.capture_button.clicked.connect(
            lambda: self.dark_requested.emit(self.exposure_box.value() / 1000, self.frames_box.value()))
        self.view = ImagePanel("mean dark frame (contrast stretched)")
        self.result = _label("The projector shows black; the frames are averaged and each pixel's spread over "
                             "them gives the camera's noise.")
        form = QFormLayout()
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.FieldsStayAtSizeHint)
        form.addRow("Exposure", self.exposure_box)
        form.addRow("Frames", self.frames_box)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.capture_button)
        layout.addWidget(self.view, 1)
        layout.addWidget(self.result)

    def show_dark(self, dark) -> None:
        """Show a :class:`~ringlight.core.capture.calibration.DarkFrame`."""
        grey = dark.mean.mean(axis=-1)
        low, high = np.percentile(grey, [1, 99])
        scaled = np.clip((grey - low) / max(high - low, 1e-6) * 255, 0, 255).astype(np.uint8)
        self.view.set_pixels(np.ascontiguousarray(np.repeat(scaled[:, :, None], 3, axis=2)))
        self.result.setText(f"{dark.frames} frames at {dark.exposure * 1000:.3g} ms: noise {dark.noise:.2f} counts rms, "
                            f"mean {dark.offset:+.2f} counts from the camera's black level {dark.black_level:g}.")


class ColourPage(QWidget):
    """The ColorChecker under the projector's white; the user clicks the four corner patches.

    Signals: ``chart_requested()``, ``fit_requested(corners)`` with corners a list of four
    (y, x) camera pixels in the order of :data:`CORNER_NAMES`.
    """

    chart_requested = Signal()
    fit_requested = Signal(list)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.corners: list[tuple[int, int]] = []
        # Short labels, the full action in the tooltip: the page fits beside the step list at 1366 px.
        self.capture_button = QPushButton("Capture chart")
        self.capture_button.setToolTip("Capture the ColorChecker under the projector's white")
        self.capture_button.clicked.connect(self.chart_requested)
        self.clear_button = QPushButton("Clear points")
        self.clear_button.clicked.connect(self.clear_corners)
        self.fit_button = QPushButton("Fit matrix")
        self.fit_button.setToolTip("Fit the camera RGB to CIE XYZ matrix to the four picked patches")
        self.fit_button.clicked.connect(lambda: self.fit_requested.emit(list(self.corners)))
        self.view = ImagePanel("ColorChecker under the projector's white: click the four corner patches")
        self.points = pg.ScatterPlotItem(symbol="o", size=12, pen=pg.mkPen("#ffd600", width=2), brush=None)
        self.points.setZValue(30)
        self.view.view.addItem(self.points)
        self.view.pixel_picked.connect(self.add_corner)
        self.instructions = _label("")
        self.result = _label("Place a ColorChecker (24 patches) in the projector's light, capture it, then "
                             "click the centres of the four corner patches.")
        buttons = QHBoxLayout()
        for button in (self.capture_button, self.clear_button, self.fit_button):
            buttons.addWidget(button)
        buttons.addStretch(1)
        layout = QVBoxLayout(self)
        layout.addLayout(buttons)
        layout.addWidget(self.view, 1)
        layout.addWidget(self.instructions)
        layout.addWidget(self.result)
        self.clear_corners()

    def show_chart(self, radiance: np.ndarray) -> None:
        """Show the white-lit chart, (rows, cols, 3) linear radiance, gamma-encoded for display
        (its 99.5th percentile white), and start picking afresh."""
        top = float(np.percentile(radiance, 99.5)) or 1.0
        display = np.clip(np.nan_to_num(radiance) / top, 0.0, 1.0) ** (1 / 2.2) * 255
        self.view.set_pixels(np.ascontiguousarray(np.round(display), np.uint8))
        self.clear_corners()

    def add_corner(self, y: int, x: int) -> None:
        if self.view.pixels() is None or len(self.corners) == len(CORNER_NAMES):
            return
        self.corners.append((y, x))
        self._update_points()

    def clear_corners(self) -> None:
        self.corners = []
        self._update_points()

    def _update_points(self) -> None:
        # Scatter positions are (x, y) at pixel centres.
        self.points.setData([x + 0.5 for _, x in self.corners], [y + 0.5 for y, _ in self.corners])
        self.fit_button.setEnabled(len(self.corners) == len(CORNER_NAMES))
        if len(self.corners) < len(CORNER_NAMES):
            self.instructions.setText(f"Click the centre of patch {CORNER_NAMES[len(self.corners)]}.")
        else:
            self.instructions.setText("Four patches picked: fit the matrix (or clear and pick again).")

    def show_fit(self, fit) -> None:
        """Show a :class:`~ringlight.core.capture.calibration.ColourFit`."""
        rows = "\n".join("  [" + ", ".join(f"{value:.4f}" for value in row) + "]" for row in fit.colorspace()["matrix"])
        self.result.setText(f"Camera RGB to CIE XYZ, scaled so that camera white has Y = 1; the dataset records it "
                            f"as its colourspace:\n{rows}\nresidual {fit.residual:.4f} (XYZ of the patches, white "
                            f"Y = 1) over 24 patches.")
