"""The dataset manifest (``dataset.json``): parsing and validation against format version 1
(docs/format/dataset.md).

Parsing never touches image data: it checks the manifest's structure, types and geometry
(lit points inside the grid, multiplexed points far enough apart) and returns a frozen
:class:`Manifest`. Every problem raises :class:`DatasetError` naming the manifest and the key.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..colourspaces import parse_colourspace
from ..errors import DatasetError
from ..validation import Validator, decode_json, read_bounded, short_repr
from .file_paths import FileResolver
from .frame_table import (  # noqa: F401 - FrameEntry and the limits are the manifest's names too
    FLOAT32_MAX,
    FLOAT32_TINY,
    MAX_REPLICATE,
    FrameCollector,
    FrameEntry,
    FrameTable,
)
from .manifest_frames import parse_frames
from .sample import Sample, parse_sample
from .spacing import POINTS_AT_ONCE, check_multiplexed_spacing

FORMAT_NAME = "ringlight-impulse"
FORMAT_VERSION = 1
MANIFEST_NAME = "dataset.json"

_TOP_KEYS = {
    "format", "version", "grid", "colorspace", "frame_space", "mapping", "max_radius",
    "frames", "dark", "ground_truth", "notes", "channels", "part", "sample",
}
_GRID_KEYS = {"height", "width", "pitch_mm"}
_TRUTH_KEYS = {"path_length_images", "layers"}
_PATH_IMAGE_KEYS = {"file", "min", "max"}
_LAYER_KEYS = {"name", "depth", "rgb"}
MAX_GRID_POINTS = 2**26
"""Largest grid (H x W) a manifest may declare: 8192 x 8192, far beyond any projector."""
MAX_RADIUS_LIMIT = 1024.0
"""Largest ``max_radius`` (grid steps) a manifest may declare."""


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
    """A name in ``colour.RGB_COLOURSPACES``: the manifest's name, or the registered name of its
    primaries or matrix (:func:`~ringlight.core.colourspaces.parse_colourspace`)."""
    frame_space: str
    mapping: str | None
    max_radius: float | None
    frames: FrameTable
    """The frames (:class:`.frame_table.FrameTable`; a sequence of FrameEntry given here is made one)."""
    dark: str | None
    ground_truth: GroundTruth | None
    notes: str | None
    channels: tuple[str, ...] | None = None
    """Frame channels to read: three for R, G, B or one for a monochrome camera; None: R, G, B,
    or ``Y`` when frames hold a single ``Y`` and no R, G, B (see :mod:`.frames`)."""
    part: str | None = None
    """Name of the part of multi-part frames to read; None: the one part holding the channels."""
    sample: Sample = Sample()
    """The surface's stated refractive index and anisotropy (both None when not stated)."""
    source_sha256: str | None = None
    """SHA-256 (hex) of the ``dataset.json`` bytes this was read from; None when built in memory.
    A dataset's store keeps a copy of the manifest under it (:mod:`.manifest_copy`), so a
    manifest changed after reading (``dataclasses.replace``) must set it to None."""

    def __post_init__(self) -> None:
        if not isinstance(self.frames, FrameTable):
            object.__setattr__(self, "frames", FrameTable.from_entries(self.frames))

    @property
    def path(self) -> Path:
        return self.folder / MANIFEST_NAME

    @property
    def multiplexed(self) -> bool:
        """True when some frame lights more than one point (parallel capture)."""
        return bool(len(self.frames) and self.frames.counts.max() > 1)

    @property
    def replicates(self) -> tuple[int, ...]:
        """The replicate labels of the frames, sorted: two or more when the capture was repeated
        independently (a rig's repeated scans, a simulator's independent batches), each replicate
        lighting the same points, so that the spread of anything computed from each replicate
        alone measures the noise of the whole, noise shared by lit points included."""
        return tuple(np.unique(self.frames.replicates).tolist())

    def lit_counts(self) -> np.ndarray:
        """(H, W) int32: in how many frames each grid point is lit (0 = missing).

        Memory: the (H, W) int32 result plus arrays the size of the lit points, never an
        (H * W) int64 temporary.
        """
        lit = self.frames.lit
        result = np.zeros(self.height * self.width, np.int32)
        for start in range(0, len(lit), POINTS_AT_ONCE):  # bounded temporaries, however many points
            chunk = lit[start:start + POINTS_AT_ONCE]
            points, counts = np.unique(chunk[:, 0] * self.width + chunk[:, 1], return_counts=True)
            result[points] += counts.astype(np.int32)
        return result.reshape(self.height, self.width)

    def file_path(self, name: str, allow_outside: bool = False) -> Path:
        """The path of file ``name`` of the manifest, checked to stay inside the dataset folder.

        A file (or a folder on its way, such as ``frames/``) that is a symbolic link resolving
        outside the dataset folder is refused unless ``allow_outside`` (for labs that keep frames
        on another disk and link them in).
        """
        return FileResolver(self.folder, allow_outside)(name)

    def referenced_files(self) -> list[str]:
        """Every file the manifest names that loading reads (frames, dark, mapping)."""
        files = list(self.frames.files)
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
    folder, path = locate_manifest(folder)
    data = read_bounded(path, DatasetError, "manifest")
    return parse_manifest(decode_manifest(data, path), folder, source_sha256=hashlib.sha256(data).hexdigest())


def decode_manifest(data: bytes, path: Path) -> object:
    """The manifest's JSON document decoded, each frame made a row of a table as it is decoded
    (:class:`.frame_table.FrameCollector`; :func:`parse_manifest` validates the rest)."""
    return decode_json(data, path, DatasetError, "manifest", element_hooks={"frames": FrameCollector})


def locate_manifest(folder: str | Path) -> tuple[Path, Path]:
    """The dataset folder and its ``dataset.json`` for a folder or its manifest; DatasetError
    naming the path when either is missing or cannot be reached."""
    folder = Path(folder)
    try:
        if folder.name == MANIFEST_NAME and not folder.is_dir():
            folder = folder.parent
        path = folder / MANIFEST_NAME
        if not folder.exists():
            raise DatasetError(f"{folder}: no such dataset folder")
        if not folder.is_dir():
            raise DatasetError(f"{folder}: is a file, not a dataset folder or its {MANIFEST_NAME}")
        if not path.exists():
            raise DatasetError(f"{path}: manifest not found")
    except OSError as error:  # a name too long, a permission denied on the way
        raise DatasetError(f"{folder}: cannot be read ({error.strerror or error})") from None
    return folder, path


def parse_manifest(document: object, folder: Path, *, source_sha256: str | None = None,
                   frames: FrameTable | None = None) -> Manifest:
    """Validate a manifest already decoded from JSON; see :func:`read_manifest`.

    ``frames``: the frames of this manifest, validated before (a store's copy of it): its
    ``frames`` key is then not read, nor their spacing checked again.
    """
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
    if height * width > MAX_GRID_POINTS:
        raise DatasetError(f"{where}: grid {height} x {width} has over {MAX_GRID_POINTS:,} points; "
                           "no projector region is that large")
    pitch_mm = check.positive_number(grid["pitch_mm"], "grid.pitch_mm") if "pitch_mm" in grid else None

    try:
        colorspace = parse_colourspace(doc.get("colorspace", "sRGB"))
    except ValueError as problem:
        raise DatasetError(f"{where}: 'colorspace' {problem}") from None
    channels = _parse_channels(check, doc["channels"]) if "channels" in doc else None
    part = check.string(doc["part"], "part") if "part" in doc else None
    frame_space = check.string(doc.get("frame_space", "grid"), "frame_space")
    if frame_space not in ("grid", "camera"):
        raise DatasetError(f"{where}: 'frame_space' must be \"grid\" or \"camera\", not {frame_space!r}")
    mapping = check.relative_file(doc["mapping"], "mapping") if "mapping" in doc else None
    if frame_space == "camera" and mapping is None:
        raise DatasetError(f"{where}: 'frame_space' \"camera\" needs a 'mapping' file")
    if frame_space == "grid" and mapping is not None:
        raise DatasetError(f"{where}: 'mapping' is only allowed with 'frame_space' \"camera\"")
    max_radius = check.positive_number(doc["max_radius"], "max_radius") if "max_radius" in doc else None
    if max_radius is not None and max_radius > MAX_RADIUS_LIMIT:
        raise DatasetError(f"{where}: 'max_radius' {max_radius:g} is over {MAX_RADIUS_LIMIT:g} grid steps")
    dark = check.relative_file(doc["dark"], "dark") if "dark" in doc else None
    notes = check.string(doc["notes"], "notes") if "notes" in doc else None
    sample = parse_sample(check, doc["sample"]) if "sample" in doc else Sample()

    checked = frames is not None
    if not checked:
        frames = parse_frames(check, check.sequence(doc["frames"], "frames"), height, width)
    if not frames:
        raise DatasetError(f"{where}: 'frames' is empty")
    manifest = Manifest(
        folder=folder, height=height, width=width, pitch_mm=pitch_mm, colorspace=colorspace,
        frame_space=frame_space, mapping=mapping, max_radius=max_radius, frames=frames, dark=dark,
        ground_truth=_parse_ground_truth(check, doc["ground_truth"]) if "ground_truth" in doc else None,
        notes=notes, channels=channels, part=part, sample=sample, source_sha256=source_sha256,
    )
    if not checked and len(manifest.replicates) > 1:
        _check_replicates(where, manifest)
    if manifest.multiplexed:
        if max_radius is None:
            raise DatasetError(f"{where}: frames light several points at once, so 'max_radius' is required")
        if not checked:
            check_multiplexed_spacing(where, frames, max_radius)
    return manifest


def _check_replicates(where: Path, manifest: Manifest) -> None:
    """Every replicate must light the same points (else a point's noise has no replicate spread)."""
    frames = manifest.frames
    keys = frames.lit[:, 0] * manifest.width + frames.lit[:, 1]
    label_of_point = np.repeat(frames.replicates, frames.counts)
    labels = manifest.replicates
    first = np.unique(keys[label_of_point == labels[0]])
    for label in labels[1:]:
        points = np.unique(keys[label_of_point == label])
        if not np.array_equal(points, first):
            raise DatasetError(f"{where}: replicate {label} lights {len(points)} points and replicate {labels[0]} "
                               f"{len(first)}{'' if len(points) != len(first) else ' others'}: every replicate must "
                               "light the same points")


def _parse_channels(check: Validator, value: object) -> tuple[str, ...]:
    """The ``channels`` key: three distinct non-empty names (R, G, B) or one (monochrome)."""
    names = tuple(check.string(name, f"channels[{index}]")
                  for index, name in enumerate(check.sequence(value, "channels")))
    if len(names) not in (1, 3) or len(set(names)) != len(names) or not all(names):
        raise DatasetError(f"{check.where}: 'channels' must be three distinct channel names for R, G, B "
                           f"or one for a monochrome camera, got {short_repr(value)}")
    return names


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
