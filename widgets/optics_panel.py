"""The Optics tab: a map of absorption mu_a or reduced scattering mu_s' of one channel, with its
colour bar, the controls that compute it (progress, cancel), the calibration in use and the
readouts the window gives (hovered pixel, region statistics).

The panel shows what it is given (:meth:`OpticsPanel.set_map`) and reports what the user did;
the window computes the maps and the texts.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from .colormaps import lut
from .image_panel import ImagePanel

QUANTITIES = {"mua": "mu_a", "musp": "mu_s'"}
"""Property keys of :class:`ringlight.core.optics.OpticalMaps` and their names on screen."""
CHANNELS = ("R", "G", "B")
MAP_COLORMAP = "viridis"
UNDEFINED_RGB = (90, 90, 90)
"""Pixels without a fitted value (NaN)."""
UNDETERMINED_DIM = 0.45
"""Brightness of pixels whose value is not determined (:attr:`OpticalMaps.determined` False)."""


def map_levels(values: np.ndarray, keep: np.ndarray) -> tuple[float, float]:
    """Levels of a property map: the 1st and 99th percentiles of its ``keep`` (H, W) finite
    values (a few badly fitted pixels would squeeze the rest into one colour); (0, 1) when none."""
    finite = values[keep & np.isfinite(values)]
    if not len(finite):
        return 0.0, 1.0
    low, high = (float(v) for v in np.percentile(finite, (1.0, 99.0)))
    return (low, high) if high > low else (low - 0.5 * abs(low) - 1e-12, high + 0.5 * abs(high) + 1e-12)


def map_pixels(values: np.ndarray, levels: tuple[float, float], determined: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 colours of an (H, W) property map on :data:`MAP_COLORMAP` over
    ``levels``: NaN grey, pixels not ``determined`` dimmed."""
    table = lut(MAP_COLORMAP)
    low, high = levels
    with np.errstate(invalid="ignore"):
        fraction = np.clip((values - low) / (high - low), 0.0, 1.0)
    index = np.nan_to_num(fraction * (len(table) - 1), nan=0.0).astype(np.intp)
    pixels = table[index].astype(np.float32)
    pixels[~determined] *= UNDETERMINED_DIM
    pixels[~np.isfinite(values)] = UNDEFINED_RGB
    return pixels.astype(np.uint8)


class OpticsPanel(QWidget):
    """Controls and map of the optical properties.

    Signals
    -------
    compute_requested()
        Compute the maps of the dataset on screen.
    export_requested()
        Write the maps shown to a file.
    fit_region_requested()
        Fit the mean E(r) of the region (the Layers tab's, else the whole grid).
    cancel_requested()
        Stop the maps' computation and the region fit.
    calibration_requested()
        Choose a calibration file.
    calibration_cleared()
        Use no calibration (a simulated, absolute dataset).
    choice_changed()
        Another quantity or channel was chosen.
    pixel_picked(y, x), pixel_hovered(y, x)
        As :class:`.image_panel.ImagePanel`'s.
    """

    compute_requested = Signal()
    export_requested = Signal()
    fit_region_requested = Signal()
    cancel_requested = Signal()
    calibration_requested = Signal()
    calibration_cleared = Signal()
    choice_changed = Signal()
    pixel_picked = Signal(int, int)
    pixel_hovered = Signal(int, int)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.compute_button = QPushButton("Compute maps")
        self.compute_button.setToolTip("Fit mu_a and mu_s' of a homogeneous half-space to every pixel's E(r) "
                                       "(rings 0, 1, ... up to the dataset's max_radius)")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.fit_region_button = QPushButton("Fit region")
        self.fit_region_button.setToolTip("Fit mu_a and mu_s' to the mean E(r) of the Layers tab's region (else the "
                                          "whole grid): one fit, its standard errors those of the region's profile")
        self.export_button = QPushButton("Export…")
        self.export_button.setToolTip("The maps, their standard errors and flags as one EXR file (File > Export "
                                      "optical maps as EXR)")
        self.progress_bar = QProgressBar()
        self.progress_bar.setRange(0, 1000)
        self.progress_bar.setTextVisible(False)
        self.quantity_box = QComboBox()
        for key, name in QUANTITIES.items():
            self.quantity_box.addItem(name, key)
        self.channel_box = QComboBox()
        self.channel_box.addItems(CHANNELS)
        self.n_edit = QLineEdit()
        self.n_edit.setPlaceholderText("manifest's")
        self.n_edit.setToolTip("Refractive index of the sample (e.g. 1.4 for tissue); empty: the manifest's sample.n")
        self.g_edit = QLineEdit()
        self.g_edit.setPlaceholderText("manifest's or 0")
        self.g_edit.setToolTip("Henyey-Greenstein anisotropy; empty: the manifest's sample.g, else 0 (isotropic)")
        self.calibration_label = QLabel("Calibration: none (absolute, simulated data)")
        self.calibration_label.setWordWrap(True)
        self.calibration_button = QPushButton("Calibration…")
        self.calibration_button.setToolTip("A calibration file (ringlight optics --calibrate, or the capture "
                                           "wizard's \"Calibrate on a reference\") for a real rig's scans")
        self.clear_calibration_button = QPushButton("None")
        self.clear_calibration_button.setToolTip("Use no calibration: the dataset's values are absolute")
        self.image_panel = ImagePanel()
        self.hover_label = QLabel()
        self.hover_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.hover_label.setWordWrap(True)
        self.region_label = QLabel()
        self.region_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.region_label.setWordWrap(True)
        self.region_fit_label = QLabel()
        self.region_fit_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.region_fit_label.setWordWrap(True)

        # Two rows: in one, the four buttons and the progress bar made the dock wider than a
        # 1366-pixel screen leaves it.
        buttons = QHBoxLayout()
        buttons.addWidget(self.compute_button)
        buttons.addWidget(self.fit_region_button)
        buttons.addWidget(self.export_button)
        working = QHBoxLayout()
        working.addWidget(self.cancel_button)
        working.addWidget(self.progress_bar, 1)
        choices = QGridLayout()
        choices.addWidget(QLabel("Quantity"), 0, 0)
        choices.addWidget(self.quantity_box, 0, 1)
        choices.addWidget(QLabel("Channel"), 0, 2)
        choices.addWidget(self.channel_box, 0, 3)
        choices.addWidget(QLabel("n"), 1, 0)
        choices.addWidget(self.n_edit, 1, 1)
        choices.addWidget(QLabel("g"), 1, 2)
        choices.addWidget(self.g_edit, 1, 3)
        calibration = QHBoxLayout()
        calibration.addWidget(self.calibration_label, 1)
        calibration.addWidget(self.calibration_button)
        calibration.addWidget(self.clear_calibration_button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addLayout(buttons)
        layout.addLayout(working)
        layout.addLayout(choices)
        layout.addLayout(calibration)
        layout.addWidget(self.image_panel, 1)
        layout.addWidget(self.hover_label)
        layout.addWidget(self.region_label)
        layout.addWidget(self.region_fit_label)

        self.compute_button.clicked.connect(self.compute_requested)
        self.cancel_button.clicked.connect(self.cancel_requested)
        self.export_button.clicked.connect(self.export_requested)
        self.fit_region_button.clicked.connect(self.fit_region_requested)
        self.calibration_button.clicked.connect(self.calibration_requested)
        self.clear_calibration_button.clicked.connect(self.calibration_cleared)
        self.quantity_box.currentIndexChanged.connect(lambda _: self.choice_changed.emit())
        self.channel_box.currentIndexChanged.connect(lambda _: self.choice_changed.emit())
        self.image_panel.pixel_picked.connect(self.pixel_picked)
        self.image_panel.pixel_hovered.connect(self.pixel_hovered)
        self.set_map(None)

    def quantity(self) -> str:
        """``"mua"`` or ``"musp"``."""
        return self.quantity_box.currentData()

    def channel(self) -> int:
        """Index of the chosen channel (0 R, 1 G, 2 B)."""
        return self.channel_box.currentIndex()

    def sample(self) -> tuple[float | None, float | None]:
        """The refractive index and anisotropy typed (None where empty: the manifest's); ValueError
        with one line when one is not a number."""
        values = []
        for name, edit in (("n", self.n_edit), ("g", self.g_edit)):
            text = edit.text().strip()
            try:
                values.append(float(text) if text else None)
            except ValueError:
                raise ValueError(f"{name} must be a number, got {text!r}") from None
        return values[0], values[1]

    def set_busy(self, busy: bool) -> None:
        """A computation runs (the maps or the region fit: Cancel offered) or not; the progress bar
        starts again from 0."""
        self.cancel_button.setEnabled(busy)
        self.progress_bar.setValue(0)

    def set_progress(self, fraction: float) -> None:
        self.progress_bar.setValue(round(1000 * min(max(fraction, 0.0), 1.0)))

    def set_calibration(self, text: str) -> None:
        self.calibration_label.setText(f"Calibration: {text}")

    def set_map(self, values: np.ndarray | None, determined: np.ndarray | None = None, label: str = "",
                title: str = "", whole: np.ndarray | None = None) -> None:
        """Show the (H, W) map ``values`` with a colour bar titled ``label``; None: no map, ``title``
        says why. Pixels not ``determined``, or not ``whole`` (H, W) (their rings cut by the grid's
        edge or by unlit points: biased fits), are dimmed, and the levels are those of the others where there are any
        (an edge's biased pixels would otherwise set the colours of a nearly uniform map)."""
        self.export_button.setEnabled(values is not None)
        if values is None:
            self.image_panel.clear_image()
            self.image_panel.set_colour_bar(None)
            self.image_panel.set_title(title or "No maps yet: Compute maps")
            self.levels = None
            return
        keep = np.ones(values.shape, bool) if determined is None else determined
        trusted = keep if whole is None else keep & whole
        self.levels = map_levels(values, trusted if (trusted & np.isfinite(values)).any() else keep)
        self.image_panel.set_pixels(map_pixels(values, self.levels, trusted))
        self.image_panel.set_colour_bar(self.levels, pg.colormap.get(MAP_COLORMAP), label)
        self.image_panel.set_title(title)

    def set_hover(self, text: str) -> None:
        self.hover_label.setText(text)

    def set_region(self, text: str) -> None:
        self.region_label.setText(text)

    def set_region_fit(self, text: str) -> None:
        """The region fit's result (or what it is doing); empty: none."""
        self.region_fit_label.setText(text)

    def show_point(self, y: int, x: int) -> None:
        """Mark the picked grid point on the map."""
        if self.image_panel.grid_shape is not None:
            self.image_panel.marker.setData([x + 0.5], [y + 0.5])
