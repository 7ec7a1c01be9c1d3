"""The Layers tab: region choice, picked radii, method, the chromaticity diagram and swatches."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QPushButton,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)
from ringlight.core.colour.chroma import METHODS, LayerResult
from ringlight.core.inversion.settings import DEFAULT_DEPTH
from ringlight.core.inversion.report import DatasetInversion

from .chromaticity_diagram import FIT_KEY, PICKS_KEY, ChromaticityDiagram
from .inversion_fit_plot import InversionFitPlot

REGION_MODES = {"all": "All pixels", "rectangle": "Rectangle", "polygon": "Polygon"}
_COLUMNS = ["layer", "r", "x", "y", "recovered", "truth", "true x, y", "xy error", "SNR", "trusted"]
_INVERSE_COLUMNS = ["layer", "depth", "x", "y", "recovered", "truth", "true x, y", "xy error", "2-sigma width",
                    "determined"]
INVERSE = "inverse"
METHOD_TIPS = {
    "paper": "paper: white + chromaticity differences of transient images at picked radii",
    "radiance": "radiance: unit-luminance RGB mixing of transient images at picked radii",
    INVERSE: "inverse: fit a layered model to the region's ring-light profile (F); each layer's colour "
             "comes with a two-sigma region, and layers the data do not bound are greyed",
}


INDEX_STEP = 0.05
"""Step of the refractive index box; one step below 1 is "auto"."""

class LayerPanel(QWidget):
    """Shows a trajectory and recovered layers; reports what the user asks for.

    Signals
    -------
    pick_requested()
        Toggle the current radius among the picked ones.
    clear_requested(), auto_requested(int)
        Clear the picks; propose N radii.
    method_changed(str), region_mode_changed(str)
        A key of ``METHODS`` / :data:`REGION_MODES`.
    radius_clicked(float)
        A trajectory point was clicked.
    export_requested(str)
        ``"json"``, ``"csv"`` or ``"png"`` (the diagram).
    fit_requested()
        Fit the layered model (the inverse method) with :meth:`inversion_inputs`.
    """

    pick_requested = Signal()
    clear_requested = Signal()
    auto_requested = Signal(int)
    method_changed = Signal(str)
    region_mode_changed = Signal(str)
    radius_clicked = Signal(float)
    export_requested = Signal(str)
    fit_requested = Signal()

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.region_box = QComboBox()
        for key, label in REGION_MODES.items():
            self.region_box.addItem(label, key)
        self.region_box.setToolTip("Region averaged for the trajectory; drag the ROI on the image to move it")
        self.method_box = QComboBox()
        for key in (*METHODS, INVERSE):
            self.method_box.addItem(key, key)
            self.method_box.setItemData(self.method_box.count() - 1, METHOD_TIPS[key], Qt.ItemDataRole.ToolTipRole)
        self.method_box.setToolTip("\n".join(METHOD_TIPS.values()))
        pick = QPushButton("Pick radius (P)")
        pick.setToolTip("Add the current radius to the picks, or remove it")
        pick.clicked.connect(self.pick_requested)
        clear = QPushButton("Clear")
        clear.clicked.connect(self.clear_requested)
        self.auto_box = QSpinBox()
        self.auto_box.setRange(1, 8)
        self.auto_box.setValue(3)
        auto = QPushButton("Auto")
        auto.setToolTip("Propose this many radii, equally spaced up to where the signal fades")
        auto.clicked.connect(lambda: self.auto_requested.emit(self.auto_box.value()))
        self.layers_box = QComboBox()
        for text in ("auto", "1", "2", "3", "4"):
            self.layers_box.addItem(text)
        self.layers_box.setToolTip("Number of layers, or auto: 1 to 4 compared by BIC")
        self.boundaries_edit = QLineEdit()
        self.boundaries_edit.setPlaceholderText("searched")
        self.boundaries_edit.setToolTip("Depths (whole grid steps) where layers meet, e.g. 2,5; empty: searched")
        self.mus_edit = QLineEdit()
        self.mus_edit.setPlaceholderText("auto")
        self.mus_edit.setToolTip("Scattering coefficient per grid step: one common value, or one per layer "
                                 "(with boundaries); empty: searched, common or with a base of its own")
        # The index's lowest value, one step below 1, reads "auto": searched by the fit.
        self.n_box = QDoubleSpinBox()
        self.n_box.setRange(1.0 - INDEX_STEP, 3.0)
        self.n_box.setSingleStep(INDEX_STEP)
        self.n_box.setSpecialValueText("auto")
        self.n_box.setToolTip("Refractive index of the sample; auto: the dataset's when its manifest states one "
                              "(sample.n), else chosen by the fit from the usual indices")
        self.g_box = QDoubleSpinBox()
        self.g_box.setRange(-0.95, 0.95)
        self.g_box.setSingleStep(0.05)
        self.g_box.setToolTip("Henyey-Greenstein anisotropy of the scattering (the dataset's sample.g when stated)")
        self.set_sample(None, None)
        self.depth_box = QDoubleSpinBox()
        self.depth_box.setRange(10.0, 256.0)
        self.depth_box.setDecimals(0)
        self.depth_box.setValue(DEFAULT_DEPTH)
        self.depth_box.setToolTip("Thickness of the modelled sample, grid steps (light below it is lost)")
        fit = QPushButton("Fit (F)")
        fit.setToolTip("Fit the layered model to the region's profile in the background (Esc cancels)")
        fit.clicked.connect(self.fit_requested)
        self.picked_label = QLabel("Picked radii: none")
        self.message_label = QLabel()
        self.message_label.setWordWrap(True)
        self.region_statistics_label = QLabel()  # wrapped here: one status-bar line could not hold it at 1366 px
        self.region_statistics_label.setWordWrap(True)
        self.region_statistics_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.region_statistics_label.setToolTip("Pixel count, mean and standard deviation of the shown image "
                                                "over the region")
        self.diagram = ChromaticityDiagram()
        self.diagram.radius_clicked.connect(self.radius_clicked)
        self.fit_plot = InversionFitPlot()
        self.fit_plot.setVisible(False)
        self.table = QTableWidget(0, len(_COLUMNS))
        self.table.setHorizontalHeaderLabels(_COLUMNS)
        self._trust_rule = ""
        self.table.verticalHeader().setVisible(False)
        # Columns as wide as their header and cells (100 px each cut "depth" and "xy error" at 1366 px).
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.table.setMaximumHeight(150)
        exports = QHBoxLayout()
        for key, label in (("json", "Export JSON…"), ("csv", "Export CSV…"), ("png", "Diagram PNG…")):
            button = QPushButton(label)
            button.clicked.connect(lambda _=False, key=key: self.export_requested.emit(key))
            exports.addWidget(button)

        # Two rows of controls: one row would make the Analysis dock too wide for a 1366 px screen.
        choices, picking = QHBoxLayout(), QHBoxLayout()
        for widget in (QLabel("Region"), self.region_box, QLabel("Method"), self.method_box):
            choices.addWidget(widget)
        for widget in (pick, clear, self.auto_box, auto):
            picking.addWidget(widget)
        choices.addStretch(1)
        picking.addStretch(1)
        self.picking_row = QWidget()
        self.picking_row.setLayout(picking)
        picking.setContentsMargins(0, 0, 0, 0)
        model, optics = QHBoxLayout(), QHBoxLayout()
        for widget in (QLabel("Layers"), self.layers_box, QLabel("Boundaries"), self.boundaries_edit,
                       QLabel("mus"), self.mus_edit):
            model.addWidget(widget)
        for widget in (QLabel("n"), self.n_box, QLabel("g"), self.g_box, QLabel("depth"), self.depth_box, fit):
            optics.addWidget(widget)
        optics.addStretch(1)
        self.inverse_rows = QWidget()
        rows = QVBoxLayout(self.inverse_rows)
        rows.setContentsMargins(0, 0, 0, 0)
        rows.addLayout(model)
        rows.addLayout(optics)
        self.inverse_rows.setVisible(False)
        layout = QVBoxLayout(self)
        layout.addLayout(choices)
        layout.addWidget(self.region_statistics_label)
        layout.addWidget(self.picking_row)
        layout.addWidget(self.inverse_rows)
        layout.addWidget(self.picked_label)
        layout.addWidget(self.diagram, 1)
        layout.addWidget(self.fit_plot, 1)
        layout.addWidget(self.table)
        layout.addWidget(self.message_label)
        layout.addLayout(exports)
        self.method_box.currentIndexChanged.connect(lambda _: self._show_mode())
        self.method_box.currentIndexChanged.connect(lambda _: self.method_changed.emit(self.method()))
        self.region_box.currentIndexChanged.connect(lambda _: self.region_mode_changed.emit(self.region_mode()))

    def method(self) -> str:
        return self.method_box.currentData()

    def inversion_inputs(self) -> dict:
        """The inverse method's settings as typed: ``layers`` ("auto" or "1".."4"), ``boundaries``
        and ``mus`` (text, empty for the defaults), ``n`` (None: auto), ``g`` and ``depth`` (grid
        steps)."""
        return {"layers": self.layers_box.currentText(), "boundaries": self.boundaries_edit.text().strip(),
                "mus": self.mus_edit.text().strip(),
                "n": None if self.n_box.value() == self.n_box.minimum() else self.n_box.value(),
                "g": self.g_box.value(), "depth": self.depth_box.value()}

    def set_sample(self, n: float | None, g: float | None) -> None:
        """Show what a dataset states of its surface as the fit's index and anisotropy: ``n`` (None:
        auto, searched) and ``g`` (None: 0)."""
        self.n_box.setValue(self.n_box.minimum() if n is None else n)
        self.g_box.setValue(0.0 if g is None else g)

    def _show_mode(self) -> None:
        inverse = self.method() == INVERSE
        self.picking_row.setVisible(not inverse)
        self.picked_label.setVisible(not inverse)
        self.inverse_rows.setVisible(inverse)
        self.fit_plot.setVisible(inverse)
        self.table.setRowCount(0)
        columns = _INVERSE_COLUMNS if inverse else _COLUMNS
        self.table.setColumnCount(len(columns))
        self.table.setHorizontalHeaderLabels(columns)
        if not inverse:
            self.set_trust_rule(self._trust_rule)
        self.diagram.set_regions([], [], [])
        self.diagram.set_key(FIT_KEY if inverse else PICKS_KEY)
        self.table.setMaximumHeight(125 if inverse else 150)

    def show_inversion(self, result: DatasetInversion | None) -> None:
        """Fill the table, the diagram and the fit plot with an inversion (None clears them)."""
        self.table.setRowCount(0)
        self.diagram.set_regions([], [], [])
        self.fit_plot.clear_fit()
        if result is None:
            self.diagram.set_layers([], [])
            return
        inversion = result.inversion
        self.table.setRowCount(len(inversion.layers))
        for row, layer in enumerate(inversion.layers):
            truth_xy = result.truth_xy[row] if result.errors is not None else None
            cells = [str(row + 1), f"{layer.top:g}..{layer.bottom:g}", f"{layer.xy[0]:.4f}", f"{layer.xy[1]:.4f}",
                     "#%02x%02x%02x" % layer.swatch, result.truth_names[row] if truth_xy is not None else "",
                     "" if truth_xy is None else f"{truth_xy[0]:.4f}, {truth_xy[1]:.4f}",
                     "" if truth_xy is None else f"{result.errors[row]:.4f}"
                     + ("" if result.inside[row] else " (outside)"),
                     f"{layer.region_width:.3f} (data {layer.allowed_width:.3f})",
                     "yes" if layer.determined else "no"]
            for column, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setFlags(item.flags() & ~Qt.ItemFlag.ItemIsEditable)
                if not layer.determined:
                    item.setToolTip(layer.reason)
                    item.setForeground(QColor("#8a8a8a"))
                elif layer.limit:
                    item.setToolTip(layer.limit)
                self.table.setItem(row, column, item)
            self.table.item(row, 8).setToolTip(
                f"Two-sigma region {layer.region_width:.3f} wide in xy; the data alone allow {layer.allowed_width:.3f} "
                f"(Fisher information at the data's noise){': ' + layer.limit if layer.limit else ''}")
            self.table.item(row, 4).setBackground(QColor(*layer.swatch))
        self.table.resizeColumnsToContents()
        grey = (138, 138, 138)
        stars = [layer.swatch if layer.determined else grey for layer in inversion.layers]
        truth_xy = list(result.truth_xy) if result.truth_xy is not None else None
        self.diagram.set_layers([layer.xy for layer in inversion.layers], stars, truth_xy,
                                [(255, 255, 255)] * len(truth_xy) if truth_xy else None)
        self.diagram.set_regions([layer.region for layer in inversion.layers],
                                 [layer.swatch for layer in inversion.layers],
                                 [layer.determined for layer in inversion.layers])
        outlines = [layer.region for layer in inversion.layers if len(layer.region)]
        self.diagram.show_around(np.vstack([*outlines, *(truth_xy or []),
                                            *[layer.xy[None] for layer in inversion.layers]]))
        self.fit_plot.show_fit(inversion.measured.radii, inversion.measured.mean, inversion.model, inversion.sigma,
                               inversion.used)

    def region_mode(self) -> str:
        return self.region_box.currentData()

    def set_picked(self, radii) -> None:
        self.picked_label.setText("Picked radii: " + (", ".join(f"{r:g}" for r in radii) if radii else "none"))
        self.diagram.set_picked(radii)

    def show_message(self, text: str) -> None:
        self.message_label.setText(text)

    def set_trust_rule(self, text: str) -> None:
        """The rule behind the trusted column, shown as its tooltip (header and cells)."""
        self._trust_rule = text
        for column in (len(_COLUMNS) - 2, len(_COLUMNS) - 1):
            self.table.horizontalHeaderItem(column).setToolTip(text)

    def show_result(self, result: LayerResult | None, truth_names=(), snr=(), trust_known: bool = True) -> None:
        """Fill the swatch table and mark layers on the diagram (None clears them); ``snr``: the
        number behind each layer's trusted flag (the rule of :meth:`set_trust_rule`), which reads
        "pending" while not ``trust_known``."""
        self.table.setRowCount(0)
        if result is None:
            self.diagram.set_layers([], [])
            return
        self.table.setRowCount(len(result.layers))
        for row, layer in enumerate(result.layers):
            truth_xy = result.truth_xy[row] if result.truth_xy and row < len(result.truth_xy) else None
            truth_name = truth_names[row] if row < len(truth_names) else ""
            error = result.errors[row] if result.errors and row < len(result.errors) else None
            cells = [str(row + 1), f"{layer.radius:g}", f"{layer.xy[0]:.4f}", f"{layer.xy[1]:.4f}",
                     "#%02x%02x%02x" % layer.srgb8, truth_name,
                     "" if truth_xy is None else f"{truth_xy[0]:.4f}, {truth_xy[1]:.4f}",
                     "" if error is None else f"{error:.4f}",
                     f"{snr[row]:.3g}" if row < len(snr) and trust_known else "",
                     ("yes" if layer.trusted else "no") if trust_known else "pending"]
            for column, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setFlags(item.flags() & ~Qt.ItemFlag.ItemIsEditable)
                if column >= len(_COLUMNS) - 2:
                    note = layer.note if trust_known else "waiting for the noise estimate"
                    item.setToolTip("\n".join(filter(None, [note, self._trust_rule])))
                self.table.setItem(row, column, item)
            self.table.item(row, 4).setBackground(QColor(*layer.srgb8))
        self.table.resizeColumnsToContents()
        truth_rgb8 = list(result.truth_srgb8) if result.truth_srgb8 is not None else None
        for row, rgb8 in enumerate((truth_rgb8 or [])[:len(result.layers)]):
            self.table.item(row, 5).setBackground(QColor(*rgb8))
        self.diagram.set_layers([layer.xy for layer in result.layers], [layer.srgb8 for layer in result.layers],
                                list(result.truth_xy) if result.truth_xy else None, truth_rgb8)
