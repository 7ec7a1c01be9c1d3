"""A validated manifest kept in the dataset's store, so that a reopen need not parse its JSON.

A paper-scale manifest is large: 1024 x 1024 grid points lit 256 at a time are 4225 frames and 34
MB of JSON, which take about 3 s to decode and validate, most of a reopen. When a store is written
(:func:`write_manifest_copy`, inside the store's folder, so it is published and replaced with it),
the manifest it was built from goes with it as ``manifest.npz``: the SHA-256 of the
``dataset.json`` bytes, the manifest without its frames (JSON), and the frames as arrays (files,
exposures, lit points, and how many points each frame lights). :func:`load_manifest` reads the
manifest's bytes and hashes them (0.1 s at that size); when the copy was made from the same bytes
it is used, else the manifest is parsed.

The copy is read only when its bytes are those the store's table recorded
(:func:`.response_store.entry_file`: an edited copy, even one that keeps the digest, is not used),
every array's declared size must fit the bytes that hold it (a header claiming 10^12 points is not
allocated), and then it is checked again as far as it costs little: the manifest's keys go through
:func:`.manifest.parse_manifest` again, every file name through the same rules, and every lit point
must lie inside the grid. Only the spacing of multiplexed points and that every replicate lights
the same points are not checked again. A copy that cannot be read (damaged, of another version, not
ringlight's) is ignored.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import zipfile
from dataclasses import fields
from pathlib import Path

import numpy as np

from ..colourspaces import colourspace_json
from ..errors import DatasetError
from ..validation import Validator, decode_json, read_bounded
from .cache import cache_location
from .response_store import entry_file
from .manifest import (
    FLOAT32_MAX,
    FLOAT32_TINY,
    FORMAT_NAME,
    MAX_REPLICATE,
    FORMAT_VERSION,
    MANIFEST_NAME,
    FrameTable,
    Manifest,
    FrameCollector,
    locate_manifest,
    parse_manifest,
)
from .sample import sample_json

COPY_NAME = "manifest.npz"
COPY_VERSION = 2
"""2: frames carry their replicate labels."""
MAX_COPY_BYTES = 2**30
"""Largest copy read (its arrays unpacked): a one-point-per-frame 1024 x 1024 manifest's is 120 MB."""


def load_manifest(folder: str | Path) -> Manifest:
    """:func:`.manifest.read_manifest`, from the store's copy when that was made from the same
    ``dataset.json`` bytes. Raises DatasetError as ``read_manifest`` does."""
    folder, path = locate_manifest(folder)
    data = read_bounded(path, DatasetError, "manifest")
    digest = hashlib.sha256(data).hexdigest()
    copy = read_manifest_copy(cache_location(folder), folder, digest)
    if copy is not None:
        return copy
    document = decode_json(data, path, DatasetError, "manifest", element_hooks={"frames": FrameCollector})
    return parse_manifest(document, folder, source_sha256=digest)


def write_manifest_copy(folder: Path, manifest: Manifest) -> None:
    """Write ``manifest``'s copy into the store being written in ``folder``; nothing for a
    manifest built in memory (it has no bytes to be recognised by), or one whose keys do not
    read back the same (a copy is never allowed to differ from its manifest)."""
    if manifest.source_sha256 is None:
        return
    header = {key: value for key, value in _header(manifest).items() if value is not None}
    try:
        again = parse_manifest({**header, "frames": []}, manifest.folder, source_sha256=manifest.source_sha256,
                               frames=manifest.frames)
    except DatasetError:
        return
    if _keys(again) != _keys(manifest):
        return
    frames = manifest.frames
    np.savez(folder / COPY_NAME, version=np.int64(COPY_VERSION), digest=np.str_(manifest.source_sha256),
             header=np.frombuffer(json.dumps(header).encode("utf-8"), np.uint8),
             files=np.array(frames.files, dtype=str), exposures=frames.exposures, counts=frames.counts,
             replicates=frames.replicates, lit=frames.lit)


def _keys(manifest: Manifest) -> dict:
    """Every field of ``manifest`` but its frames."""
    return {field.name: getattr(manifest, field.name) for field in fields(manifest) if field.name != "frames"}


def read_manifest_copy(entry: Path, folder: Path, digest: str) -> Manifest | None:
    """The manifest of the copy in the store entry ``entry`` when it was made from ``dataset.json``
    bytes of SHA-256 ``digest`` and passes the checks of the module docstring; else None."""
    data = entry_file(entry, COPY_NAME)
    if data is None:
        return None
    try:
        handle = io.BytesIO(data)
        with zipfile.ZipFile(handle) as archive:
            if sum(member.file_size for member in archive.infolist()) > MAX_COPY_BYTES \
                    or not all(_fits(archive, member) for member in archive.infolist()):
                return None
        handle.seek(0)
        with np.load(handle, allow_pickle=False) as stored:
            if int(stored["version"]) != COPY_VERSION or str(stored["digest"]) != digest:
                return None
            header = json.loads(stored["header"].tobytes().decode("utf-8"))
            files, exposures = stored["files"].tolist(), stored["exposures"]
            counts, lit, replicates = stored["counts"], stored["lit"], stored["replicates"]
    except (OSError, ValueError, KeyError, TypeError, EOFError, RecursionError, MemoryError, zipfile.BadZipFile):
        return None
    try:
        return _rebuild(header, files, exposures, counts, lit, replicates, folder, digest)
    except (DatasetError, ValueError, TypeError, KeyError):
        return None


def _fits(archive: zipfile.ZipFile, member: zipfile.ZipInfo) -> bool:
    """Whether the array of ``member`` (an .npy file) declares no more bytes than it holds."""
    with archive.open(member) as stream:
        version = np.lib.format.read_magic(stream)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read_header(stream)
    return math.prod(shape) * dtype.itemsize <= member.file_size


def _rebuild(header: dict, files: list, exposures: np.ndarray, counts: np.ndarray, lit: np.ndarray,
             replicates: np.ndarray, folder: Path, digest: str) -> Manifest | None:
    frames_count = len(files)
    if (exposures.shape != (frames_count,) or counts.shape != (frames_count,) or lit.ndim != 2
            or replicates.shape != (frames_count,) or replicates.dtype != np.int64
            or np.any(replicates < 0) or np.any(replicates > MAX_REPLICATE)
            or lit.shape[1] != 2 or lit.dtype != np.int64 or counts.dtype != np.int64
            or np.any(counts < 1) or np.any(counts > len(lit)) or int(counts.sum()) != len(lit)):
        return None
    height, width = header["grid"]["height"], header["grid"]["width"]
    if not (np.all((lit[:, 0] >= 0) & (lit[:, 0] < height) & (lit[:, 1] >= 0) & (lit[:, 1] < width))
            and np.all((exposures >= FLOAT32_TINY) & (exposures <= FLOAT32_MAX))):
        return None
    check = Validator(folder / MANIFEST_NAME, DatasetError)
    for index, file in enumerate(files):
        check.relative_file(file, f"frames[{index}].file")
    frames = FrameTable(files, exposures, replicates, counts, lit)
    return parse_manifest({**header, "frames": []}, folder, source_sha256=digest, frames=frames)


def _header(manifest: Manifest) -> dict:
    """The manifest without its frames, as the JSON document it was read from says it."""
    grid = {"height": manifest.height, "width": manifest.width}
    if manifest.pitch_mm is not None:
        grid["pitch_mm"] = manifest.pitch_mm
    truth = manifest.ground_truth
    return {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "grid": grid,
        "colorspace": colourspace_json(manifest.colorspace),
        "frame_space": manifest.frame_space, "mapping": manifest.mapping, "max_radius": manifest.max_radius,
        "dark": manifest.dark, "notes": manifest.notes,
        "channels": None if manifest.channels is None else list(manifest.channels), "part": manifest.part,
        "sample": sample_json(manifest.sample),
        "ground_truth": None if truth is None else {
            "path_length_images": [{"file": image.file, "min": image.min, "max": image.max}
                                   for image in truth.path_length_images],
            "layers": [{"name": layer.name, "depth": list(layer.depth), "rgb": list(layer.rgb)}
                       for layer in truth.layers],
        },
    }
