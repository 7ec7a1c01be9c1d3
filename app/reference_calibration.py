"""The capture wizard's calibration on a reference, as a frozen request run in a worker: open the
reference's scan, fit the rig's scale (:func:`ringlight.core.optics.calibrate`) and write the
calibration file atomically, replacing only a calibration file (never a file ringlight did not
write)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ringlight.core import open_dataset
from ringlight.core.optics import Calibration, calibrate, write_calibration


@dataclass(frozen=True)
class CalibrationResult:
    """The calibration written and where."""

    path: Path
    calibration: Calibration

    def summary(self) -> str:
        scale = " ".join(f"{s:.4g}" for s in self.calibration.scale)
        return f"Calibration written to {self.path}: scale R G B {scale}"


@dataclass(frozen=True)
class ReferenceCalibration:
    """Calibrate on the scan folder ``scan`` of a reference of known ``mua``, ``musp`` (1 or 3
    values, the scan's units) and index ``n`` (None: the manifest's); write to ``out``."""

    scan: str
    mua: tuple[float, ...]
    musp: tuple[float, ...]
    n: float | None
    description: str
    out: str
    photons: int

    def run(self, progress) -> CalibrationResult:
        dataset = open_dataset(self.scan, progress=lambda fraction: progress(0.5 * fraction))
        calibration = calibrate(dataset, self.mua if len(self.mua) == 3 else self.mua[0],
                                self.musp if len(self.musp) == 3 else self.musp[0], n=self.n,
                                description=self.description, photons=self.photons)
        progress(1.0)
        out = Path(self.out)
        # Replacing only a calibration: write_calibration reads an existing file first and refuses others.
        write_calibration(out, calibration, overwrite=out.exists())
        return CalibrationResult(out, calibration)
