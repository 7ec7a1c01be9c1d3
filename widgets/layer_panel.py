"""The Layers tab: region choice, picked radii, method, the chromaticity diagram and swatches."""

from __future__ import annotations

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QComboBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)
from ringlight.core.colour.chroma import METHODS, LayerResult

from .chromaticity_diagram import ChromaticityDiagram

REGION_MODES = {"all": "All pixels", "rectangle": "Rectangle", "polygon": "Polygon"}
_COLUMNS = ["layer", "r", "x", "y", "recovered", "truth", "true x, y", "xy error", "SNR", "trusted"]


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
    """

    pick_requested = Signal()
    clear_requested = Signal()
    auto_requested = Signal(int)
    method_changed = Signal(str)
    region_mode_changed = Signal(str)
    radius_clicked = Signal(float)
    export_requested = Signal(str)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.region_box = QComboBox()
        for key, label in REGION_MODES.items():
            self.region_box.addItem(label, key)
        self.region_box.setToolTip("Region averaged for the trajectory; drag the ROI on the image to move it")
        self.method_box = QComboBox()
        for key in METHODS:
            self.method_box.addItem(key, key)
        self.method_box.setToolTip("paper: white + chromaticity differences; radiance: unit-luminance RGB mixing")
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
        self.picked_label = QLabel("Picked radii: none")
        self.message_label = QLabel()
        self.message_label.setWordWrap(True)
        self.diagram = ChromaticityDiagram()
        self.diagram.radius_clicked.connect(self.radius_clicked)
        self.table = QTableWidget(0, len(_COLUMNS))
        self.table.setHorizontalHeaderLabels(_COLUMNS)
        self._trust_rule = ""
        self.table.verticalHeader().setVisible(False)
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
        layout = QVBoxLayout(self)
        layout.addLayout(choices)
        layout.addLayout(picking)
        layout.addWidget(self.picked_label)
        layout.addWidget(self.diagram, 1)
        layout.addWidget(self.table)
        layout.addWidget(self.message_label)
        layout.addLayout(exports)
        self.method_box.currentIndexChanged.connect(lambda _: self.method_changed.emit(self.method()))
        self.region_box.currentIndexChanged.connect(lambda _: self.region_mode_changed.emit(self.region_mode()))

    def method(self) -> str:
        return self.method_box.currentData()

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
