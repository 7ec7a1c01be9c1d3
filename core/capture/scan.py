"""Parallel impulse scanning: plan, capture with a journal, resume, and the finished dataset.

Lit points are the projector pixels of a region of interest on a lattice of spacing
``floor(2 * max_radius) + 1`` (> 2 max_radius, so docs/format/dataset.md attributes all light within
max_radius of a lit point to it): (spacing)^2 frames instead of one per pixel. With a multiplexed
plan, blocks of lattice frames are captured through a Hadamard code and demultiplexed
(:mod:`.multiplex`); the dataset holds the lattice frames either way.

A scan writes into its output folder as it goes::

    OUT/.scan/plan.json       the plan and the camera's description: what a resume continues
    OUT/.scan/journal.jsonl   one line per finished frame, flushed and fsynced
    OUT/.scan/projector.jsonl the projector checks (:mod:`.projector_check`)
    OUT/frames/NNNNN.exr      each merged HDR frame, written atomically as soon as it exists
    OUT/mapping.exr, OUT/dark.exr
    OUT/dataset.json          written last: the folder is a dataset only once the scan is complete

Preparation follows :mod:`..atomic`'s rule for folder outputs: ``mapping.exr``, ``frames/`` and
``.scan/plan.json`` are built in a hidden ``.OUT.partial-HEX`` beside ``OUT`` and published with
one rename, onto an absent or empty ``OUT`` only. A new scan never deletes or replaces anything in
``OUT``: a folder holding anything (a user's ``mapping.exr``, ``.scan/notes.txt``, a
``.mapping.partial-0123456789ab.exr``) is refused with one line. An interrupted preparation leaves
``OUT`` as it was and, at most, its locked staging folder beside it, which the next fresh run
sweeps once no process holds its lock (:func:`..staging_locks.sweep_abandoned`). A resumed scan
removes only the hidden temporaries of the files a scan writes (``.00003.partial-HEX.exr`` in
``frames/``), never another hidden file.

A scan stopped anywhere (cancel, crash, power cut, a camera that stops answering, a full disk)
resumes from the journal; frames are deterministic functions of the rig and the camera's
description is kept in the plan, so the resumed dataset is byte for byte an uninterrupted one.
"""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import psutil

from ..atomic import OutputError, atomic_file, fsync_path, output_folder
from ..dataset.exr import write_exr_channels, write_exr_rgb
from ..dataset.manifest import parse_manifest
from ..dataset.memory import format_bytes, memory_budget
from ..errors import Cancelled, RinglightError
from ..ownership import Owned, temporary_of
from ..staging_locks import sweep_abandoned
from .hardware import Camera, HardwareError, Projector
from .hdr import merge_brackets
from .multiplex import block_bytes, coded_lit, demultiplex
from .projector_check import CHECK_EVERY, CHECK_NAME, ProjectorCheck
from .scan_folder import check_scan_folder
from .scan_plan import (
    BYTES_PER_PIXEL,
    PLAN_NAME,
    SCAN_FOLDER,
    ScanError,
    ScanPaused,
    ScanPlan,
    read_plan,
)

CAPTURE_TIMEOUT_S = 30.0
_PREPARATION = Owned(frozenset({"mapping.exr", "frames"}), (SCAN_FOLDER,))
"""What a preparation's staging folder holds: an abandoned one holding anything else is not swept."""
_WRITTEN = {
    "": re.compile(r"mapping\.exr|dark\.exr|dataset\.json"),
    "frames": re.compile(r"[0-9]{5}\.exr"),
    SCAN_FOLDER: re.compile(r"[^/]+"),
    f"{SCAN_FOLDER}/saturated": re.compile(r"[0-9]{5}\.png"),
}
"""Per folder of a scan (relative to ``OUT``), the names of the files a scan writes there: a hidden
temporary of one of them is a write cut short, removed on resume; any other is left alone."""


def capture_with_timeout(camera: Camera, exposure: float, timeout: float = CAPTURE_TIMEOUT_S) -> np.ndarray:
    """``camera.capture(exposure)``, or HardwareError when it does not return within ``timeout``
    seconds (a hung driver cannot be killed, but the scan does not hang with it)."""
    results: queue.Queue = queue.Queue(maxsize=1)

    def run():
        try:
            results.put(("frame", camera.capture(exposure)))
        except BaseException as error:  # handed to the caller, raised there
            results.put(("error", error))

    threading.Thread(target=run, daemon=True, name="camera-capture").start()
    try:
        kind, value = results.get(timeout=timeout + exposure)
    except queue.Empty:
        raise HardwareError(f"the camera did not answer within {timeout + exposure:.0f} s") from None
    if kind == "error":
        if isinstance(value, HardwareError):
            raise value
        raise HardwareError(f"the camera failed: {type(value).__name__}: {value}") from value
    return np.asarray(value, np.float32)


def capture_hdr(camera: Camera, projector: Projector, pattern: np.ndarray | None, plan: ScanPlan,
                timeout: float = CAPTURE_TIMEOUT_S):
    """Show ``pattern`` (None: black), capture the bracket and merge it: a MergedFrame in camera
    counts per second, RGB (a mono camera's frame is repeated in three channels)."""
    if pattern is None:
        projector.show_black()
    else:
        projector.show(pattern)
    if projector.settle_time > 0:
        time.sleep(projector.settle_time)
    frames = [as_rgb(capture_with_timeout(camera, exposure, timeout)) for exposure in plan.exposures]
    return merge_brackets(frames, plan.exposures, camera.black_level, camera.saturation_level, plan.noise_floor)


def as_rgb(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame, np.float32)
    if frame.ndim == 2:
        return np.repeat(frame[:, :, None], 3, axis=2)
    if frame.ndim == 3 and frame.shape[2] == 3:
        return frame
    raise HardwareError(f"camera frames must be (rows, cols) or (rows, cols, 3), got {frame.shape}")


@dataclass(frozen=True)
class ScanProgress:
    """Frames done of total; ``drift``: the projector check's latest relative change of the lit
    impulse's radiance from the first check (None before two checks)."""

    done: int
    total: int
    drift: float | None = None


class Scan:
    """A scan into ``out`` (see the module docstring); :meth:`run` captures what is missing."""

    def __init__(self, out, plan: ScanPlan, mapping: np.ndarray, camera_notes: str = "",
                 colorspace: str | dict = "sRGB", check_every: int = CHECK_EVERY):
        """``colorspace``: the manifest's value (a name, or ``{"matrix": M}`` from the colour
        step); ``check_every``: frames between projector checks (0: none)."""
        self.out = Path(out)
        self.plan = plan
        self.mapping = np.asarray(mapping, np.float32)
        self.camera_notes = camera_notes
        self.colorspace = colorspace
        self.frames = plan.frames()
        frame_bytes = self.mapping.shape[0] * self.mapping.shape[1] * BYTES_PER_PIXEL
        if plan.multiplex and block_bytes(plan.multiplex, frame_bytes) > (budget := _block_budget()):
            raise ScanError(f"a block of {plan.multiplex} multiplexed captures of {self.mapping.shape[1]} x "
                            f"{self.mapping.shape[0]} pixels holds {format_bytes(block_bytes(plan.multiplex, frame_bytes))} "
                            f"at once, more than the {format_bytes(budget)} of memory ringlight may use "
                            "($RINGLIGHT_MEMORY_BUDGET); choose a smaller --multiplex")
        self.projector_check = ProjectorCheck(self.out / SCAN_FOLDER / CHECK_NAME, self.frames[0], self.mapping,
                                              check_every, len(self.frames), plan.max_radius)

    @property
    def plan_path(self) -> Path:
        return self.out / SCAN_FOLDER / PLAN_NAME

    @property
    def journal_path(self) -> Path:
        return self.out / SCAN_FOLDER / "journal.jsonl"

    def prepare(self, resume: bool) -> None:
        """Publish a new scan (plan, mapping, folders), or check that a resumed scan continues
        the same plan and take its camera description from the plan."""
        if resume and self.plan_path.exists():
            stored, self.camera_notes, self.colorspace = read_plan(self.out)
            if stored != self.plan:
                raise ScanError(f"{self.plan_path}: the unfinished scan has another plan; resume with its settings")
            self._clear_temporaries()
            self._repair_journal()
            return
        check_scan_folder(self.out)
        try:
            sweep_abandoned(self.out, kinds=("partial",), holds=_PREPARATION)
            self._publish_scan()
        except OSError as error:  # OUT's folder read-only (OutputError says so itself)
            raise ScanError(f"{self.out}: cannot prepare the scan: {error.strerror or error}") from error

    def _publish_scan(self) -> None:
        """Build the preparation in a staging folder and rename it onto the absent or empty ``OUT``."""
        with output_folder(self.out, lambda folder: None, "scan", replace=False) as staging:
            (staging / "frames").mkdir()
            with atomic_file(staging / "mapping.exr", make_parents=False, durable=True) as temporary:
                write_exr_channels(temporary, {"y": self.mapping[..., 0], "x": self.mapping[..., 1]})
            (staging / SCAN_FOLDER).mkdir()
            with atomic_file(staging / SCAN_FOLDER / PLAN_NAME, make_parents=False, durable=True) as temporary:
                temporary.write_text(self.plan.to_json(self.camera_notes, self.colorspace), encoding="utf-8")
            fsync_path(staging)
        fsync_path(self.out.parent)  # the scan exists from here on, whole

    def _clear_temporaries(self) -> None:
        """Remove the files of writes cut short by a crash (their frames are captured again): the
        hidden temporaries of the names a scan writes (:data:`_WRITTEN`), nothing else."""
        for relative, written in _WRITTEN.items():
            folder = self.out / relative
            if not folder.is_dir():
                continue
            for entry in folder.iterdir():
                target = temporary_of(entry.name)
                if target is not None and written.fullmatch(target) and not entry.is_dir():
                    entry.unlink()

    def _repair_journal(self) -> None:
        """Cut a line torn by a crash, so that the next entry starts on a line of its own."""
        if not self.journal_path.is_file():
            return
        data = self.journal_path.read_bytes()
        if data and not data.endswith(b"\n"):
            with open(self.journal_path, "r+b") as journal:
                journal.truncate(data.rfind(b"\n") + 1)
                journal.flush()
                os.fsync(journal.fileno())

    def finished_frames(self) -> dict[int, dict]:
        """Journal entries by frame index, for frames whose file exists (a torn or foreign line
        is ignored: its frame is captured again)."""
        entries = {}
        if self.journal_path.exists():
            for line in self.journal_path.read_text(encoding="utf-8", errors="replace").splitlines():
                try:
                    entry = json.loads(line)
                    index = entry["index"]
                    valid = (type(index) is int and 0 <= index < len(self.frames)
                             and entry.get("file") == _frame_name(index))
                except (ValueError, TypeError, KeyError, AttributeError, RecursionError):
                    continue  # a torn or hostile line: that frame is captured again
                if valid and (self.out / entry["file"]).is_file():
                    entries[index] = entry
        return entries

    def run(self, camera: Camera, projector: Projector, progress: Callable[[ScanProgress], None] | None = None,
            should_stop: Callable[[], bool] | None = None, timeout: float = CAPTURE_TIMEOUT_S) -> Path:
        """Capture the dark frame and every unfinished block of frames (with the projector checks),
        then write the manifest.

        Raises ScanPaused (camera failure, disk full, a write refused) or Cancelled
        (``should_stop``), leaving a resumable scan; ScanError when the scan's folder vanished;
        returns the dataset folder when complete.
        """
        frame_bytes = self.mapping.shape[0] * self.mapping.shape[1] * BYTES_PER_PIXEL
        done = self.finished_frames()
        saturated = sum(entry.get("saturated", 0) for entry in done.values())
        check = self.projector_check
        try:
            if not (self.out / "dark.exr").is_file():
                self._check_disk(frame_bytes)
                dark = capture_hdr(camera, projector, None, self.plan, timeout)
                self._write_exr("dark.exr", dark.radiance)
            for indices, code in self.plan.blocks():
                if all(index in done for index in indices):
                    continue
                if should_stop is not None and should_stop():
                    raise Cancelled(f"scan stopped after {len(done)} of {len(self.frames)} frames; resume to continue")
                if check.due(indices):
                    self._check_projector(indices[0], camera, projector, timeout)
                self._check_disk(frame_bytes * len(indices))
                captures = [capture_hdr(camera, projector, self.plan.pattern(lit, projector.size), self.plan, timeout)
                            for lit in coded_lit(self.frames, indices, code)]
                recovered = demultiplex(np.stack([merged.radiance for merged in captures]), code)
                # A recovered frame mixes every capture of its block: saturated where any of them is.
                mask = np.any([merged.saturated.any(axis=-1) for merged in captures], axis=0)
                for index, radiance in zip(indices, recovered):
                    self._write_exr(_frame_name(index), radiance.astype(np.float32))
                    count = int(mask.sum()) if code is not None else captures[0].saturated_count
                    if count:
                        self._write_saturation_mask(index, mask)
                    entry = {"index": index, "file": _frame_name(index), "saturated": count}
                    self._append_journal(entry)
                    done[index] = entry
                    saturated += count
                if progress is not None:
                    progress(ScanProgress(len(done), len(self.frames), check.drift()))
            if check.due(range(len(self.frames), len(self.frames) + 1)):
                self._check_projector(len(self.frames), camera, projector, timeout)
            return self._write_manifest(saturated)
        except HardwareError as error:
            raise ScanPaused(f"scan paused after {len(done)} of {len(self.frames)} frames: {error}; "
                             "fix the camera and resume") from None
        except (OSError, OutputError) as error:
            raise self._write_failed(error, len(done)) from error
        finally:
            projector.show_black()

    def _check_projector(self, frame: int, camera: Camera, projector: Projector, timeout: float) -> None:
        """Show the reference lattice frame and record its radiance (:mod:`.projector_check`)."""
        projector.show(self.plan.pattern(self.projector_check.lit, projector.size))
        if projector.settle_time > 0:
            time.sleep(projector.settle_time)
        exposure = min(self.plan.exposures)
        image = as_rgb(capture_with_timeout(camera, exposure, timeout))
        self.projector_check.record(frame, image, exposure, camera.black_level)

    def _write_failed(self, error: OSError | OutputError, done: int) -> RinglightError:
        """One line for a write that failed: a full disk or a read-only folder pauses the scan;
        a scan folder deleted meanwhile cannot be resumed."""
        if not self.plan_path.is_file():
            return ScanError(f"{self.out}: the scan's folder was removed during the scan (no {SCAN_FOLDER}/"
                             f"{PLAN_NAME}); start the scan again")
        if isinstance(error, OSError):
            reason = f"{error.filename or self.out}: {error.strerror or error}"
        else:
            reason = str(error).splitlines()[0]
        return ScanPaused(f"scan paused after {done} of {len(self.frames)} frames: {reason}; "
                          "free some space (or fix the folder) and resume")

    def _write_exr(self, name: str, image: np.ndarray) -> None:
        # Never recreate a folder deleted meanwhile (make_parents=False): the write fails instead.
        with atomic_file(self.out / name, overwrite=True, make_parents=False, durable=True) as temporary:
            write_exr_rgb(temporary, image)

    def _write_saturation_mask(self, index: int, mask: np.ndarray) -> None:
        folder = self.out / SCAN_FOLDER / "saturated"
        folder.mkdir(exist_ok=True)
        path = folder / f"{index:05d}.png"
        with atomic_file(path, overwrite=True, make_parents=False) as temporary:
            if not cv2.imwrite(str(temporary), mask.astype(np.uint8) * 255):
                raise OutputError(f"{path}: could not write a saturation mask")

    def saturation_map(self) -> np.ndarray:
        """(rows, cols) float32: frames in which each camera pixel saturated in every bracket."""
        counts = np.zeros(self.mapping.shape[:2], np.float32)
        for path in sorted((self.out / SCAN_FOLDER / "saturated").glob("[0-9]*.png")):
            counts += cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 0
        return counts

    def _append_journal(self, entry: dict) -> None:
        with open(self.journal_path, "a", encoding="utf-8") as journal:
            journal.write(json.dumps(entry) + "\n")
            journal.flush()
            os.fsync(journal.fileno())

    def _check_disk(self, needed: int) -> None:
        free = shutil.disk_usage(self.out).free
        if free < 2 * needed:
            raise ScanPaused(f"{self.out}: only {format_bytes(free)} free, a frame needs {format_bytes(needed)}; "
                             "free some space and resume")

    def _write_manifest(self, saturated: int) -> Path:
        height, width = self.plan.grid_shape
        saturation = self.saturation_map()
        self._write_exr(f"{SCAN_FOLDER}/saturation.exr", np.repeat(saturation[:, :, None], 3, axis=2))
        notes = (f"captured by ringlight: roi {list(self.plan.roi)}, exposures "
                 f"{', '.join(f'{e:g}' for e in self.plan.exposures)} s merged to counts/s; "
                 f"{saturated} pixel-frames saturated in every bracket (per camera pixel: "
                 f"{SCAN_FOLDER}/saturation.exr). {self.projector_check.summary()} {self.camera_notes}").strip()
        manifest = {
            "format": "ringlight-impulse", "version": 1, "grid": {"height": height, "width": width},
            "colorspace": self.colorspace, "frame_space": "camera", "mapping": "mapping.exr",
            "max_radius": self.plan.max_radius, "dark": "dark.exr", "notes": notes,
            "frames": [{"file": _frame_name(index), "lit": lit.tolist(), "exposure": 1.0}
                       for index, lit in enumerate(self.frames)],
        }
        parse_manifest(manifest, self.out)  # never publish a manifest the reader would refuse
        with atomic_file(self.out / "dataset.json", overwrite=True, make_parents=False, durable=True) as temporary:
            temporary.write_text(json.dumps(manifest), encoding="utf-8")
        return self.out


def _block_budget() -> int:
    """Bytes a multiplexed block may hold: ``$RINGLIGHT_MEMORY_BUDGET`` when set, else half the
    memory available now (a scan does nothing else meanwhile, unlike an open beside the window)."""
    if os.environ.get("RINGLIGHT_MEMORY_BUDGET"):
        return memory_budget()
    return int(0.5 * psutil.virtual_memory().available)


def _frame_name(index: int) -> str:
    return f"frames/{index:05d}.exr"
