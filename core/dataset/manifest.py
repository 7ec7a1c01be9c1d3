"""The dataset manifest (``dataset.json``): parsing and validation against FORMAT.md v1.

Parsing never touches image data: it checks the manifest's structure, types and geometry
(lit points inside the grid, multiplexed points far enough apart) and returns a frozen
:class:`Manifest`. Every problem raises :class:`DatasetError` naming the manifest and the key.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..colourspaces import is_known_colourspace
from ..errors import DatasetError
from ..validation import Validator

FORMAT_NAME = "ringlight-impulse"
FORMAT_VERSION = 1
MANIFEST_NAME = "dataset.json"

_TOP_KEYS = {
    "format", "version", "grid", "colorspace", "frame_space", "mapping", "max_radius",
    "frames", "dark", "ground_truth", "notes",
}
_GRID_KEYS = {"height", "width", "pitch_mm"}
_FRAME_KEYS = {"file", "lit", "exposure"}
_TRUTH_KEYS = {"path_length_images", "layers"}
_PATH_IMAGE_KEYS = {"file", "min", "max"}
_LAYER_KEYS = {"name", "depth", "rgb"}


@dataclass(frozen=True, eq=False)
class FrameEntry:
    """One captured frame: its file (relative to the dataset folder), lit points and exposure.

    ``lit`` is an (n, 2) int64 array of grid positions ``[y, x]``.
    """

    file: str
    lit: np.ndarray
    exposure: float


@dataclass(frozen=True)
class PathLengthImage:
    """A ground-truth image of the light whose path length lies in ``[min, max)`` grid steps."""

    file: str
    min: float
    max: float


@dataclass(frozen=True)
class Layer:
    """A layer of a synthetic layered surface: depth range (grid steps) and reference linear RGB."""

    name: str
    depth: tuple[float, float]
    rgb: tuple[float, float, float]


@dataclass(frozen=True)
class GroundTruth:
    path_length_images: tuple[PathLengthImage, ...] = ()
    layers: tuple[Layer, ...] = ()


@dataclass(frozen=True, eq=False)
class Manifest:
    """A validated ``dataset.json``. Paths are relative to ``folder``."""

    folder: Path
    height: int
    width: int
    pitch_mm: float | None
    colorspace: str
    frame_space: str
    mapping: str | None
    max_radius: float | None
    frames: tuple[FrameEntry, ...]
    dark: str | None
    ground_truth: GroundTruth | None
    notes: str | None

    @property
    def path(self) -> Path:
        return self.folder / MANIFEST_NAME

    @property
    def multiplexed(self) -> bool:
        """True when some frame lights more than one point (parallel capture)."""
        return any(len(frame.lit) > 1 for frame in self.frames)

    def lit_counts(self) -> np.ndarray:
        """(H, W) int32: in how many frames each grid point is lit (0 = missing)."""
        counts = np.zeros((self.height, self.width), np.int32)
        for frame in self.frames:
            np.add.at(counts, (frame.lit[:, 0], frame.lit[:, 1]), 1)
        return counts

    def referenced_files(self) -> list[str]:
        """Every file the manifest names that loading reads (frames, dark, mapping)."""
        files = [frame.file for frame in self.frames]
        files += [name for name in (self.dark, self.mapping) if name is not None]
        return files


def read_manifest(folder: str | Path) -> Manifest:
    """Read and validate ``folder/dataset.json`` (``folder`` may also be the manifest itself).

    Raises
    ------
    DatasetError
        Naming the manifest and the problem: missing file, invalid JSON, wrong ``format`` or
        ``version``, an unknown key, a key of the wrong type, a lit point outside the grid,
        multiplexed points closer than ``2 * max_radius``.
    """
    folder = Path(folder)
    if folder.name == MANIFEST_NAME and not folder.is_dir():
        folder = folder.parent
    path = folder / MANIFEST_NAME
    if not folder.exists():
        raise DatasetError(f"{folder}: no such dataset folder")
    if not path.is_file():
        raise DatasetError(f"{path}: manifest not found")
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as error:
        raise DatasetError(f"{path}: cannot be read ({error})") from None
    except json.JSONDecodeError as error:
        raise DatasetError(f"{path}: invalid JSON at line {error.lineno}: {error.msg}") from None
    return parse_manifest(document, folder)


def parse_manifest(document: object, folder: Path) -> Manifest:
    """Validate a manifest already decoded from JSON; see :func:`read_manifest`."""
    where = folder / MANIFEST_NAME
    check = Validator(where, DatasetError)
    doc = check.mapping(document, "manifest", _TOP_KEYS, required={"format", "version", "grid", "frames"})
    if doc["format"] != FORMAT_NAME:
        raise DatasetError(f"{where}: 'format' is {doc['format']!r}, expected {FORMAT_NAME!r}")
    if doc["version"] != FORMAT_VERSION or isinstance(doc["version"], bool):
        raise DatasetError(
            f"{where}: unsupported 'version' {doc['version']!r} (this ringlight reads version {FORMAT_VERSION})"
        )
    grid = check.mapping(doc["grid"], "grid", _GRID_KEYS, required={"height", "width"})
    height = check.positive_int(grid["height"], "grid.height")
    width = check.positive_int(grid["width"], "grid.width")
    pitch_mm = check.positive_number(grid["pitch_mm"], "grid.pitch_mm") if "pitch_mm" in grid else None

    colorspace = check.string(doc.get("colorspace", "sRGB"), "colorspace")
    if not is_known_colourspace(colorspace):
        raise DatasetError(f"{where}: 'colorspace' {colorspace!r} is not a colour-science RGB colourspace")
    frame_space = check.string(doc.get("frame_space", "grid"), "frame_space")
    if frame_space not in ("grid", "camera"):
        raise DatasetError(f"{where}: 'frame_space' must be \"grid\" or \"camera\", not {frame_space!r}")
    mapping = check.relative_file(doc["mapping"], "mapping") if "mapping" in doc else None
    if frame_space == "camera" and mapping is None:
        raise DatasetError(f"{where}: 'frame_space' \"camera\" needs a 'mapping' file")
    if frame_space == "grid" and mapping is not None:
        raise DatasetError(f"{where}: 'mapping' is only allowed with 'frame_space' \"camera\"")
    max_radius = check.positive_number(doc["max_radius"], "max_radius") if "max_radius" in doc else None
    dark = check.relative_file(doc["dark"], "dark") if "dark" in doc else None
    notes = check.string(doc["notes"], "notes") if "notes" in doc else None

    frames = tuple(
        _parse_frame(check, entry, index, height, width)
        for index, entry in enumerate(check.sequence(doc["frames"], "frames"))
    )
    if not frames:
        raise DatasetError(f"{where}: 'frames' is empty")
    manifest = Manifest(
        folder=folder, height=height, width=width, pitch_mm=pitch_mm, colorspace=colorspace,
        frame_space=frame_space, mapping=mapping, max_radius=max_radius, frames=frames, dark=dark,
        ground_truth=_parse_ground_truth(check, doc["ground_truth"]) if "ground_truth" in doc else None,
        notes=notes,
    )
    if manifest.multiplexed:
        if max_radius is None:
            raise DatasetError(f"{where}: frames light several points at once, so 'max_radius' is required")
        _check_multiplexed_spacing(where, frames, max_radius)
    return manifest


def _parse_frame(check: Validator, entry: object, index: int, height: int, width: int) -> FrameEntry:
    name = f"frames[{index}]"
    frame = check.mapping(entry, name, _FRAME_KEYS, required={"file", "lit"})
    file = check.relative_file(frame["file"], f"{name}.file")
    points = check.sequence(frame["lit"], f"{name}.lit")
    if not points:
        raise DatasetError(f"{check.where}: {name} ({file}) lights no point")
    lit = np.empty((len(points), 2), np.int64)
    for row, point in enumerate(points):
        if (
            not isinstance(point, list) or len(point) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) for v in point)
        ):
            raise DatasetError(f"{check.where}: {name}.lit[{row}] must be [y, x] integers, got {point!r}")
        y, x = point
        if not (0 <= y < height and 0 <= x < width):
            raise DatasetError(
                f"{check.where}: {name} ({file}) lights [{y}, {x}], outside the {height} x {width} grid"
            )
        lit[row] = point
    if len({(int(y), int(x)) for y, x in lit}) != len(lit):
        raise DatasetError(f"{check.where}: {name} ({file}) lists a lit point twice")
    exposure = check.positive_number(frame.get("exposure", 1.0), f"{name}.exposure")
    return FrameEntry(file=file, lit=lit, exposure=exposure)


def _parse_ground_truth(check: Validator, value: object) -> GroundTruth:
    truth = check.mapping(value, "ground_truth", _TRUTH_KEYS, required=set())
    images = []
    for index, entry in enumerate(check.sequence(truth.get("path_length_images", []), "ground_truth.path_length_images")):
        name = f"ground_truth.path_length_images[{index}]"
        item = check.mapping(entry, name, _PATH_IMAGE_KEYS, required=_PATH_IMAGE_KEYS)
        low = check.number(item["min"], f"{name}.min")
        high = check.number(item["max"], f"{name}.max")
        if not 0 <= low < high:
            raise DatasetError(f"{check.where}: {name} needs 0 <= min < max, got [{low}, {high})")
        images.append(PathLengthImage(check.relative_file(item["file"], f"{name}.file"), low, high))
    layers = []
    for index, entry in enumerate(check.sequence(truth.get("layers", []), "ground_truth.layers")):
        name = f"ground_truth.layers[{index}]"
        item = check.mapping(entry, name, _LAYER_KEYS, required=_LAYER_KEYS)
        depth = check.numbers(item["depth"], f"{name}.depth", 2)
        rgb = check.numbers(item["rgb"], f"{name}.rgb", 3)
        layers.append(Layer(check.string(item["name"], f"{name}.name"), depth, rgb))
    return GroundTruth(tuple(images), tuple(layers))


def _check_multiplexed_spacing(where: Path, frames: tuple[FrameEntry, ...], max_radius: float) -> None:
    limit_sq = (2.0 * max_radius) ** 2
    for index, frame in enumerate(frames):
        lit = frame.lit.astype(np.float64)
        for start in range(0, len(lit), 512):
            block = lit[start:start + 512]
            dist_sq = ((block[:, None, :] - lit[None, :, :]) ** 2).sum(-1)
            rows = np.arange(len(block))
            dist_sq[rows, start + rows] = np.inf
            if (dist_sq <= limit_sq).any():
                a, b = np.unravel_index(np.argmin(dist_sq), dist_sq.shape)
                p, q = frame.lit[start + a], frame.lit[b]
                raise DatasetError(
                    f"{where}: frames[{index}] ({frame.file}) lights {p.tolist()} and {q.tolist()} "
                    f"{math.sqrt(dist_sq[a, b]):.3g} apart; multiplexed points must be more than "
                    f"2 * max_radius = {2 * max_radius:g} apart"
                )
