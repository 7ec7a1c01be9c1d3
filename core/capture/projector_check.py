"""The projector check: does the light of one lit impulse stay constant over a scan?

A projector's lamp or LED warms up and ages; a scan that takes hours mixes frames lit at different
powers. Every ``every`` frames (and once after the last) the scan shows the first lattice frame's
pattern again and records the mean radiance (counts per second above black, one frame at the
shortest exposure) of the camera pixels within max_radius of its lit points, one JSON line per
check in ``OUT/.scan/projector.jsonl``. The drift is each check's radiance relative to the first
(``+0.02``: 2 % brighter); the manifest's notes give its range.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

CHECK_EVERY = 25
"""Frames between projector checks of a scan."""
CHECK_NAME = "projector.jsonl"


def near_lit(mapping: np.ndarray, lit: np.ndarray, max_radius: float) -> np.ndarray:
    """(rows, cols) bool: camera pixels whose grid position (``mapping`` (rows, cols, 2), NaN
    where none) is within ``max_radius`` grid steps of a lit point of ``lit`` (n, 2)."""
    y, x = mapping[..., 0], mapping[..., 1]
    near = np.zeros(y.shape, bool)
    finite = np.isfinite(y)
    for ly, lx in lit:
        near |= finite & (np.hypot(np.where(finite, y, 0) - ly, np.where(finite, x, 0) - lx) <= max_radius)
    return near


class ProjectorCheck:
    """The checks of one scan, kept in the JSON-lines file ``path``.

    ``lit``: (n, 2) the reference lattice frame's lit points; ``mapping``: the scan's camera ->
    grid mapping; ``every``: frames between checks (0: no checks); ``total``: the scan's frames;
    ``max_radius``: grid steps around the lit points whose light is measured (all of an impulse's
    light: the more electrons, the less shot noise in each check).
    """

    def __init__(self, path: Path, lit: np.ndarray, mapping: np.ndarray, every: int, total: int,
                 max_radius: float):
        self.path = Path(path)
        self.lit = np.asarray(lit)
        self.near = near_lit(mapping, self.lit, max_radius)
        self.every = every
        self.total = total

    def entries(self) -> list[dict]:
        """Recorded checks in order, ``{"frame": index, "radiance": value}`` (a torn line is skipped)."""
        entries = []
        if self.path.is_file():
            for line in self.path.read_text(encoding="utf-8", errors="replace").splitlines():
                try:
                    entry = json.loads(line)
                    entries.append({"frame": int(entry["frame"]), "radiance": float(entry["radiance"])})
                except (ValueError, TypeError, KeyError):
                    continue
        return entries

    def due(self, frames: range) -> bool:
        """True when a check belongs before the block of ``frames`` (a multiple of ``every`` is
        among them; ``range(total, total + 1)``: after the last frame) and none is recorded under
        its first frame yet (a resumed scan does not repeat it)."""
        if not self.every or not any(frame % self.every == 0 or frame == self.total for frame in frames):
            return False
        return all(entry["frame"] != frames[0] for entry in self.entries())

    def record(self, frame: int, image: np.ndarray, exposure: float, black_level: float) -> float:
        """Record the check before ``frame`` from ``image`` (rows, cols, 3) raw counts taken at
        ``exposure`` seconds; returns its radiance in counts per second above black."""
        pixels = image[self.near] if self.near.any() else image.reshape(-1, image.shape[-1])
        radiance = float(np.mean(pixels) - black_level) / exposure
        with open(self.path, "a", encoding="utf-8") as journal:
            journal.write(json.dumps({"frame": frame, "radiance": radiance}) + "\n")
            journal.flush()
            os.fsync(journal.fileno())
        return radiance

    def drifts(self) -> np.ndarray:
        """(checks,) each check's radiance relative to the first, minus 1."""
        radiances = np.array([entry["radiance"] for entry in self.entries()])
        if len(radiances) == 0 or radiances[0] <= 0:
            return np.zeros(0)
        return radiances / radiances[0] - 1

    def drift(self) -> float | None:
        """The latest check's drift, or None before two checks."""
        drifts = self.drifts()
        return float(drifts[-1]) if len(drifts) > 1 else None

    def summary(self) -> str:
        """One sentence for the manifest's notes ("" without checks)."""
        drifts = self.drifts()
        if len(drifts) < 2:
            return ""
        return (f"Projector check: {len(drifts)} measurements of a lit impulse, radiance "
                f"{drifts.min():+.2%} to {drifts.max():+.2%} of the first.")
