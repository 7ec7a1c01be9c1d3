"""Writing impulse datasets (format version 1, ``docs/format/dataset.md``) atomically::

    with DatasetWriter("sample", (48, 48), max_radius=16) as writer:
        writer.add_frame(image, lit=[[8, 8], [8, 41]])
    # "sample/" appears complete here, or not at all

Everything is written into a hidden staging folder beside the target and renamed into place
when the ``with`` block ends cleanly; an exception, Ctrl-C or a kill leaves no dataset behind.
An earlier dataset is replaced only on request and only when the folder holds nothing but what
ringlight wrote there (the rule of :mod:`ringlight.core.atomic`).
"""

from __future__ import annotations

import json
import os
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from ..atomic import OutputError, check_output_folder, output_folder
from ..colourspaces import colourspace_json
from ..errors import DatasetError
from ..ownership import Owned
from ..staging_locks import sweep_abandoned
from ..validation import read_json
from .cache import CACHE_FOLDER_NAME
from .exr import write_exr_channels, write_exr_rgb
from .manifest import FORMAT_NAME, FORMAT_VERSION, MANIFEST_NAME, parse_manifest
from .sample import Sample, sample_json

RINGLIGHT_SUBFOLDERS = (CACHE_FOLDER_NAME, ".scan")
"""Folders ringlight keeps inside a dataset: the cache and a capture's scan record."""


_STAGED = Owned(frozenset({MANIFEST_NAME, "dark.exr", "mapping.exr"}), ("frames", "ground_truth"))
"""What a :class:`DatasetWriter`'s staging folder holds: an abandoned one holding anything else
is not swept."""


def is_dataset_folder(path: Path) -> bool:
    """True when ``path`` holds a manifest of the ringlight impulse format."""
    return dataset_files(Path(path)) is not None


def dataset_files(folder: Path) -> Owned | None:
    """What a dataset in ``folder`` consists of: its manifest, every file the manifest names
    (frames, dark, mapping, ground-truth images) and ringlight's subfolders; None when
    ``folder`` holds no ringlight impulse manifest."""
    try:
        manifest = read_json(Path(folder) / MANIFEST_NAME, DatasetError, "dataset manifest")
    except DatasetError:
        return None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT_NAME:
        return None
    names = [manifest.get("dark"), manifest.get("mapping")]
    truth = manifest.get("ground_truth")
    for entries in (manifest.get("frames"), truth.get("path_length_images") if isinstance(truth, dict) else None):
        if isinstance(entries, list):
            names += [entry.get("file") for entry in entries if isinstance(entry, dict)]
    return Owned(frozenset([MANIFEST_NAME, *(name for name in names if isinstance(name, str))]),
                 RINGLIGHT_SUBFOLDERS)


def refuse_dataset_file(output, folder) -> None:
    """Raise :class:`~ringlight.core.atomic.OutputError` when writing the file ``output`` would
    replace a file of the dataset in ``folder`` (its manifest, a file the manifest names, or
    anything in ringlight's subfolders), with ``--force`` too: a result written over the dataset
    it was computed from destroyed it (``layers DATASET --json DATASET/dataset.json --force``).
    Links are followed to what they reach."""
    owned = dataset_files(Path(folder))
    if owned is None:
        return
    try:
        relative = Path(os.path.realpath(output)).relative_to(os.path.realpath(folder)).as_posix()
    except ValueError:  # outside the dataset's folder
        return
    if owned.contains(relative):
        raise OutputError(f"{output}: is a file of the dataset {folder} that this command reads; "
                          "refusing to replace it; write elsewhere")


def check_dataset_target(path, overwrite: bool = False) -> None:
    """Raise :class:`~ringlight.core.atomic.OutputError` unless a :class:`DatasetWriter` may
    write ``path`` (call it before long work, so that a refusal comes first)."""
    check_output_folder(path, dataset_files, "dataset", replace=overwrite)


class DatasetWriter:
    """Writes one impulse dataset; use as a context manager.

    Parameters
    ----------
    path
        Final dataset folder: absent, an empty folder, or (with ``overwrite``) a ringlight
        dataset holding nothing but its own files; anything else raises
        :class:`~ringlight.core.atomic.OutputError` before anything is written.
    grid_shape
        ``(H, W)`` of the grid.
    max_radius, pitch_mm, colorspace, notes
        Manifest keys (docs/format/dataset.md); None leaves a key out.
    sample
        The surface's refractive index and anisotropy, as far as known (the ``sample`` key; left
        out when nothing is stated).
    frame_space
        ``"grid"`` (frames H x W) or ``"camera"`` (call :meth:`set_mapping` first).
    half
        Store frames as half floats (smaller, about 3 significant digits).
    """

    def __init__(
        self,
        path,
        grid_shape: tuple[int, int],
        *,
        max_radius: float | None = None,
        pitch_mm: float | None = None,
        colorspace: str = "sRGB",
        frame_space: str = "grid",
        notes: str | None = None,
        sample: Sample = Sample(),
        half: bool = False,
        overwrite: bool = False,
    ):
        self.path = Path(path)
        self.overwrite = overwrite
        check_dataset_target(self.path, overwrite)
        self.manifest: dict = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "grid": {"height": int(grid_shape[0]), "width": int(grid_shape[1])},
            "colorspace": colourspace_json(colorspace),  # a custom space as its primaries or matrix
            "frame_space": frame_space,
            "frames": [],
        }
        if pitch_mm is not None:
            self.manifest["grid"]["pitch_mm"] = float(pitch_mm)
        if max_radius is not None:
            self.manifest["max_radius"] = float(max_radius)
        if notes is not None:
            self.manifest["notes"] = notes
        if (stated := sample_json(sample)) is not None:
            self.manifest["sample"] = stated
        self.half = half
        self._exit_stack: ExitStack | None = None
        self.staging: Path | None = None

    def __enter__(self) -> "DatasetWriter":
        # What a killed writer of this folder left beside it (a simulation's 160-424 KB, or a
        # dataset's gigabytes): its staging folders whose lock no process holds.
        sweep_abandoned(self.path, kinds=("partial",), holds=_STAGED)
        self._exit_stack = ExitStack()
        self.staging = self._exit_stack.enter_context(
            output_folder(self.path, dataset_files, "dataset", replace=self.overwrite))
        (self.staging / "frames").mkdir()
        return self

    def __exit__(self, kind, error, traceback) -> bool:
        if kind is None:
            try:
                self._finish()
            except BaseException as failure:
                self._close(type(failure), failure, failure.__traceback__)
                raise
        return self._close(kind, error, traceback)

    def _close(self, kind, error, traceback) -> bool:
        stack, self._exit_stack, self.staging = self._exit_stack, None, None
        return bool(stack.__exit__(kind, error, traceback))

    def _require_open(self) -> Path:
        if self.staging is None or self._exit_stack is None:
            raise RuntimeError("DatasetWriter must be used inside a 'with' block")
        return self.staging

    def add_frame(self, image: np.ndarray, lit, exposure: float = 1.0, replicate: int | None = None) -> str:
        """Write one frame: (h, w, 3) radiance x exposure, lighting the ``[y, x]`` points ``lit``,
        of independent replicate ``replicate`` of the capture (None: the key is left out).

        Returns the frame's file name relative to the dataset folder.
        """
        staging = self._require_open()
        name = f"frames/{len(self.manifest['frames']):06d}.exr"
        write_exr_rgb(staging / name, image, half=self.half)
        entry = {"file": name, "lit": [[int(y), int(x)] for y, x in np.asarray(lit).reshape(-1, 2)],
                 "exposure": float(exposure)}
        if replicate is not None:
            entry["replicate"] = int(replicate)
        self.manifest["frames"].append(entry)
        return name

    def set_dark(self, image: np.ndarray) -> None:
        """Write the dark frame (exposure-1 units, frame size)."""
        write_exr_rgb(self._require_open() / "dark.exr", image, half=self.half)
        self.manifest["dark"] = "dark.exr"

    def set_mapping(self, y: np.ndarray, x: np.ndarray) -> None:
        """Write ``mapping.exr``: camera pixel -> grid position (float, NaN where none)."""
        write_exr_channels(self._require_open() / "mapping.exr", {"y": y, "x": x})
        self.manifest["mapping"] = "mapping.exr"

    def add_path_length_image(self, image: np.ndarray, low: float, high: float) -> str:
        """Write a ground-truth image of light with path length in ``[low, high)`` grid steps."""
        truth = self.manifest.setdefault("ground_truth", {})
        images = truth.setdefault("path_length_images", [])
        name = f"ground_truth/len_{len(images):03d}.exr"
        (self._require_open() / "ground_truth").mkdir(exist_ok=True)
        write_exr_rgb(self._require_open() / name, image)
        images.append({"file": name, "min": float(low), "max": float(high)})
        return name

    def set_layers(self, layers: list[dict]) -> None:
        """Set ``ground_truth.layers``: dicts with ``name``, ``depth`` [top, bottom], ``rgb``."""
        self.manifest.setdefault("ground_truth", {})["layers"] = [
            {"name": str(layer["name"]), "depth": [float(v) for v in layer["depth"]],
             "rgb": [float(v) for v in layer["rgb"]]}
            for layer in layers
        ]

    def _finish(self) -> None:
        staging = self._require_open()
        parse_manifest(self.manifest, staging)  # never publish a manifest we could not read back
        (staging / MANIFEST_NAME).write_text(json.dumps(self.manifest, indent=1), encoding="utf-8")
