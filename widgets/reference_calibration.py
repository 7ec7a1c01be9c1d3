"""The capture wizard's "Calibrate on a reference" box: a finished scan of a reference material,
its known absorption and reduced scattering, and the calibration file to write (the rig's scale
per channel, :mod:`ringlight.core.optics.calibration`).

The box parses what was typed and reports it (``calibrate_requested``); the app does the work.
"""

from __future__ import annotations

import math

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)


def parse_coefficients(text: str, name: str) -> tuple[float, ...]:
    """One positive number, or three (R, G, B) separated by commas or spaces; ValueError with a
    line naming ``name`` otherwise."""
    parts = text.replace(",", " ").split()
    try:
        values = tuple(float(part) for part in parts)
    except ValueError:
        values = ()
    if len(values) not in (1, 3) or not all(math.isfinite(v) and v > 0 for v in values):
        raise ValueError(f"{name}: give one positive number or three (R, G, B), got {text!r}")
    return values


def calibration_path(scan: str) -> str:
    """The calibration file offered for ``scan``: beside the scan's folder, not inside it (the
    dataset's folder holds only what its manifest lists)."""
    scan = scan.rstrip("/\\")
    return f"{scan}-calibration.json" if scan else ""


class ReferenceCalibrationBox(QGroupBox):
    """Signals
    -------
    calibrate_requested(scan, mua, musp, n, description, out)
        Calibrate on the scan folder ``scan`` of a reference of absorption ``mua`` and reduced
        scattering ``musp`` (tuples of 1 or 3 floats, per mm when the scan's manifest gives
        ``grid.pitch_mm``, else per grid step), refractive index ``n`` (None: the manifest's),
        described as ``description``, into the file ``out``.
    """

    calibrate_requested = Signal(str, object, object, object, str, str)

    def __init__(self, parent: QWidget | None = None):
        super().__init__("Calibrate on a reference", parent)
        self.setToolTip("A scan of a material of known mu_a and mu_s' (a phantom) gives the rig's scale per channel; "
                        "the Explore tab's Optics maps and `ringlight optics --calibration` of later scans on the "
                        "same rig, exposure units and pitch use it")
        self.scan_edit = QLineEdit()
        self.scan_edit.setPlaceholderText("the reference's scan folder")
        self.scan_edit.textEdited.connect(lambda text: self.out_edit.setText(calibration_path(text)))
        scan_browse = QPushButton("Browse…")
        scan_browse.clicked.connect(self._browse_scan)
        self.mua_edit = QLineEdit()
        self.mua_edit.setPlaceholderText("e.g. 0.01 or 0.01, 0.012, 0.02")
        self.musp_edit = QLineEdit()
        self.musp_edit.setPlaceholderText("e.g. 1.0 or 1.2, 1.0, 0.8")
        self.n_edit = QLineEdit()
        self.n_edit.setPlaceholderText("the manifest's sample.n")
        self.description_edit = QLineEdit()
        self.description_edit.setPlaceholderText("what the reference is")
        self.out_edit = QLineEdit()
        out_browse = QPushButton("Browse…")
        out_browse.clicked.connect(self._browse_out)
        self.calibrate_button = QPushButton("Calibrate")
        self.calibrate_button.clicked.connect(self._request)
        self.status_label = QLabel("Units: per mm when the scan's manifest gives grid.pitch_mm, else per grid step.")
        self.status_label.setWordWrap(True)
        scan = QHBoxLayout()
        scan.addWidget(self.scan_edit, 1)
        scan.addWidget(scan_browse)
        out = QHBoxLayout()
        out.addWidget(self.out_edit, 1)
        out.addWidget(out_browse)
        form = QFormLayout()
        form.addRow("Scan", scan)
        form.addRow("mu_a", self.mua_edit)
        form.addRow("mu_s'", self.musp_edit)
        form.addRow("n", self.n_edit)
        form.addRow("Description", self.description_edit)
        form.addRow("Calibration file", out)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.calibrate_button)
        layout.addWidget(self.status_label)

    def set_scan(self, folder: str) -> None:
        """Offer ``folder`` (a scan just finished) and a calibration file beside it."""
        self.scan_edit.setText(folder)
        self.out_edit.setText(calibration_path(folder))

    def set_busy(self, busy: bool) -> None:
        self.calibrate_button.setEnabled(not busy)
        if busy:
            self.status_label.setText("Calibrating ...")

    def set_status(self, text: str) -> None:
        self.status_label.setText(text)

    def _request(self) -> None:
        try:
            mua = parse_coefficients(self.mua_edit.text(), "mu_a")
            musp = parse_coefficients(self.musp_edit.text(), "mu_s'")
            n = float(self.n_edit.text()) if self.n_edit.text().strip() else None
        except ValueError as error:
            message = str(error)
            self.status_label.setText(message if message.startswith("mu_") else f"n: not a number, "
                                                                                 f"{self.n_edit.text()!r}")
            return
        if not self.scan_edit.text().strip() or not self.out_edit.text().strip():
            self.status_label.setText("Give the reference's scan folder and the calibration file to write.")
            return
        self.calibrate_requested.emit(self.scan_edit.text().strip(), mua, musp, n, self.description_edit.text(),
                                      self.out_edit.text().strip())

    def _browse_scan(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "The reference's scan", self.scan_edit.text())
        if folder:
            self.set_scan(folder)

    def _browse_out(self) -> None:
        path = QFileDialog.getSaveFileName(self, "Calibration file to write", self.out_edit.text(),
                                           "Calibration (*.json)")[0]
        if path:
            self.out_edit.setText(path)
