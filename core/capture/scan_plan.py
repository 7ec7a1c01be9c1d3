"""The plan of a parallel impulse scan: lattice, exposures, time and disk estimates, ``plan.json``.

A plan is plain data: :mod:`.scan` runs it. Errors are :class:`ScanError` naming the file.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import RinglightError
from ..simulate.lattice import lattice_frames
from ..validation import read_json
from .multiplex import code_blocks, s_matrix

SCAN_FOLDER = ".scan"
PLAN_NAME = "plan.json"
BYTES_PER_PIXEL = 12  # float32 RGB


class ScanError(RinglightError):
    """A scan cannot start or continue (bad plan, mismatched resume, disk full)."""


class ScanPaused(RinglightError):
    """The scan stopped before its end; it resumes from its journal (the message says why)."""


@dataclass(frozen=True)
class ScanPlan:
    """What to capture.

    Attributes
    ----------
    roi
        (y0, x0, y1, x1) projector pixels of the grid, end exclusive.
    max_radius
        Grid steps.
    exposures
        Bracket exposures in seconds.
    noise_floor
        Raw counts above black below which a sample is not used in the HDR merge.
    multiplex
        0: capture each lattice frame alone; n = 2^k - 1: capture blocks of n lattice frames
        through a Hadamard S-matrix code and demultiplex them (:mod:`.multiplex`).
    """

    roi: tuple[int, int, int, int]
    max_radius: float
    exposures: tuple[float, ...]
    noise_floor: float = 0.0
    multiplex: int = 0

    @property
    def grid_shape(self) -> tuple[int, int]:
        y0, x0, y1, x1 = self.roi
        return (y1 - y0, x1 - x0)

    @property
    def spacing(self) -> int:
        return int(math.floor(2 * self.max_radius)) + 1

    def frames(self) -> list[np.ndarray]:
        """Lit grid points per frame, (n, 2) [y, x] each (see :func:`lattice_frames`)."""
        return lattice_frames(*self.grid_shape, self.max_radius)

    def blocks(self) -> list[tuple[range, np.ndarray | None]]:
        """Frame indices and S-matrix (None: uncoded) of each block captured together."""
        return code_blocks(len(self.frames()), self.multiplex)

    def pattern(self, lit: np.ndarray, projector_size: tuple[int, int]) -> np.ndarray:
        """(H, W) float32 projector pattern lighting grid points ``lit``."""
        pattern = np.zeros(projector_size, np.float32)
        pattern[lit[:, 0] + self.roi[0], lit[:, 1] + self.roi[1]] = 1.0
        return pattern

    def estimated_seconds(self, seconds_per_capture_overhead: float = 0.05, settle: float = 0.0,
                          check_every: int = 0) -> float:
        """Seconds for the dark frame, the frames and the projector checks (one every
        ``check_every`` frames and one at the end; 0: none): each takes the settle time plus,
        per bracket, its exposure and the camera's overhead (readout, transfer: measure it)."""
        per_frame = settle + sum(self.exposures) + seconds_per_capture_overhead * len(self.exposures)
        frames = len(self.frames())
        checks = (frames + check_every - 1) // check_every + 1 if check_every else 0
        per_check = settle + min(self.exposures) + seconds_per_capture_overhead
        return (frames + 1) * per_frame + checks * per_check

    def estimated_bytes(self, camera_shape: tuple[int, int]) -> int:
        """Disk for frames, dark and mapping (float32 EXR, before compression)."""
        return (len(self.frames()) + 3) * camera_shape[0] * camera_shape[1] * BYTES_PER_PIXEL

    def to_json(self, camera_notes: str = "", colorspace: str | dict = "sRGB") -> str:
        """The plan as ``plan.json`` holds it, with the camera's description and colourspace
        (docs/format/dataset.md's ``colorspace`` value) for the manifest."""
        return json.dumps({**asdict(self), "camera_notes": camera_notes, "colorspace": colorspace}, sort_keys=True)

    @classmethod
    def from_document(cls, document: object) -> ScanPlan:
        """The plan of a decoded ``plan.json``; ValueError when it is not one."""
        try:
            return cls(tuple(int(v) for v in document["roi"]), float(document["max_radius"]),
                       tuple(float(e) for e in document["exposures"]), float(document.get("noise_floor", 0.0)),
                       int(document.get("multiplex", 0)))
        except (KeyError, TypeError, ValueError, AttributeError) as problem:
            raise ValueError(f"not a ringlight scan plan ({type(problem).__name__}: {problem})") from None


def read_plan(out: Path) -> tuple[ScanPlan, str, str | dict]:
    """The plan, camera description and colourspace of the unfinished scan in ``out``;
    ScanError naming ``plan.json`` when it is unreadable."""
    path = Path(out) / SCAN_FOLDER / PLAN_NAME
    document = read_json(path, ScanError, "scan plan", max_bytes=2**20)
    try:
        plan = ScanPlan.from_document(document)
    except ValueError as problem:
        raise ScanError(f"{path}: {problem}") from None
    notes = document.get("camera_notes", "")
    colorspace = document.get("colorspace", "sRGB")
    return plan, notes if isinstance(notes, str) else "", colorspace if isinstance(colorspace, str | dict) else "sRGB"


def check_plan(plan: ScanPlan, projector_size: tuple[int, int]) -> None:
    y0, x0, y1, x1 = plan.roi
    if not (0 <= y0 < y1 <= projector_size[0] and 0 <= x0 < x1 <= projector_size[1]):
        raise ScanError(f"region {plan.roi} must lie inside the {projector_size[0]} x {projector_size[1]} projector")
    if not plan.max_radius > 0:
        raise ScanError(f"max_radius must be > 0, got {plan.max_radius}")
    if not plan.exposures or min(plan.exposures) <= 0:
        raise ScanError(f"exposures must be > 0 s, got {plan.exposures}")
    if plan.multiplex:
        try:
            s_matrix(plan.multiplex)
        except RinglightError as problem:
            raise ScanError(str(problem)) from None


def estimate_disk(plan: ScanPlan, camera_shape: tuple[int, int], folder: Path) -> tuple[int, int]:
    """(bytes the scan needs, bytes free where it will be written)."""
    folder = Path(folder)
    probe = folder if folder.exists() else next((p for p in folder.parents if p.exists()), Path("."))
    return plan.estimated_bytes(camera_shape), shutil.disk_usage(probe).free
