"""Reading and writing RGB OpenEXR images as float32 numpy arrays.

Images are (H, W, 3) float32 in channel order R, G, B. Half and float files are both read;
files are written as float (32-bit) unless ``half=True``.

Every read checks the header first (:func:`check_exr`): the size against what the caller
expects, the channels, and that the file's chunk table fits in the file, so that a small
damaged or hostile file is refused before anything is decoded.
"""

from __future__ import annotations

import os
import stat
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from ..errors import DatasetError

_EXR_MAGIC = b"\x76\x2f\x31\x01"
MAX_PIXELS = 2**26
"""Largest image (pixels) decoded: 67 megapixels, beyond any camera a rig uses. The size is
checked in the header before anything is decoded, so a small file cannot claim gigabytes."""
MAX_DECODED_BYTES = 2**30
"""Largest total of all channels of a file (the library decodes every channel of a part)."""
_MAX_HEADER_BYTES = 16 * 2**20
"""Headers longer than this (huge preview attributes) skip the chunk-table check."""
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
"""Scanlines per chunk of each OpenEXR compression (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44,
B44A, DWAA, DWAB); files of other compressions skip the chunk-table check."""
_TILED, _DEEP, _MULTIPART = 0x200, 0x800, 0x1000

_QUIET_LOCK = threading.Lock()


@dataclass(frozen=True)
class ExrHeader:
    """What ringlight needs from an EXR header: image size (pixels) and channel names."""

    height: int
    width: int
    channels: tuple[str, ...]
    subsampled: tuple[str, ...]
    """Channels with an x or y sampling other than 1 (their planes are smaller than the image)."""


@contextmanager
def _quiet_library() -> Iterator[None]:
    """Silence what the OpenEXR C++ library itself prints on stdout and stderr for damaged files,
    so that the user sees ringlight's one line and nothing else.

    File descriptors 1 and 2 are process-wide, so the lock serialises the library's calls; a
    Python thread printing meanwhile loses that output, which ringlight's workers never do.
    """
    with _QUIET_LOCK:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        saved = [os.dup(1), os.dup(2)]
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 1)
            os.dup2(null, 2)
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for descriptor in (*saved, null):
                os.close(descriptor)


def _open_regular(path: Path):
    """Open ``path`` for reading if it is a regular file (following links), else DatasetError.

    O_NONBLOCK: a FIFO put in place of a frame must not block the open.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except OSError as error:
        raise DatasetError(f"{path}: cannot be read ({error.strerror or error})") from None
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        raise DatasetError(f"{path}: not a file")
    return os.fdopen(descriptor, "rb")


def _check_magic(path: Path) -> None:
    with _open_regular(path) as handle:
        try:
            magic = handle.read(4)
        except OSError as error:
            raise DatasetError(f"{path}: cannot be read ({error.strerror or error})") from None
    if magic != _EXR_MAGIC:
        raise DatasetError(f"{path}: not an OpenEXR file")


def _attributes(head: bytes, size: int) -> tuple[dict[str, bytes], int] | None:
    """Parse a single-part header: ``({name: value bytes}, offset of the chunk table)``.

    Returns None when the header runs past the bytes read but the file is longer (a header over
    :data:`_MAX_HEADER_BYTES`: not checked); raises ValueError for a header cut short or malformed.
    """
    attributes, at = {}, 8
    while True:
        end = head.find(b"\0", at)
        if end < 0:
            break
        name = head[at:end]
        if not name:
            return attributes, end + 1
        type_end = head.find(b"\0", end + 1)
        if type_end < 0 or type_end + 5 > len(head):
            break
        length = int.from_bytes(head[type_end + 1:type_end + 5], "little", signed=True)
        if length < 0:
            raise ValueError(f"attribute {name[:40]!r} has a negative size")
        at = type_end + 5 + length
        if at > len(head):
            break
        attributes[name.decode("latin-1")] = head[type_end + 5:at]
    if len(head) < size:
        return None
    raise ValueError("the header is cut short")


def _level_size(size: int, level: int, round_up: bool) -> int:
    # OpenEXR's levelSize: size / 2**level, rounded as the file's tile description says.
    return max(-(-size // (1 << level)) if round_up else size >> level, 1)


def _level_count(size: int, round_up: bool) -> int:
    log = size.bit_length() - 1  # floor(log2(size))
    return log + 1 + (1 if round_up and size != 1 << log else 0)


def _chunk_count(attributes: dict[str, bytes], tiled: bool) -> tuple[int, int] | None:
    """``(entries, first)``: the chunk table's length in a single-part file and how many of its
    entries, at its start, hold the full-resolution level; None for a compression not known here.
    """
    window = attributes.get("dataWindow")
    compression = attributes.get("compression")
    if window is None or len(window) != 16 or compression is None or len(compression) != 1:
        raise ValueError("the header lacks a valid dataWindow or compression")
    x_min, y_min, x_max, y_max = np.frombuffer(window, "<i4").tolist()
    width, height = x_max - x_min + 1, y_max - y_min + 1
    if width <= 0 or height <= 0 or width * height > MAX_PIXELS:
        return None  # reported from the library's header with the size it reads
    if not tiled:
        lines = _LINES_PER_CHUNK.get(compression[0])
        return None if lines is None else (-(-height // lines),) * 2
    tiles = attributes.get("tiles")
    if tiles is None or len(tiles) != 9:
        raise ValueError("a tiled file without a valid tile description")
    tile_x, tile_y = np.frombuffer(tiles[:8], "<u4").tolist()
    mode, round_up = tiles[8] & 0x0F, bool(tiles[8] >> 4)
    if tile_x == 0 or tile_y == 0 or mode > 2:
        raise ValueError("an invalid tile description")

    def count(level_x: int, level_y: int) -> int:
        return (-(-_level_size(width, level_x, round_up) // tile_x)
                * -(-_level_size(height, level_y, round_up) // tile_y))

    if mode == 0:
        total = count(0, 0)
    elif mode == 1:
        total = sum(count(level, level) for level in range(_level_count(max(width, height), round_up)))
    else:
        total = sum(count(lx, ly) for lx in range(_level_count(width, round_up))
                    for ly in range(_level_count(height, round_up)))
    return total, count(0, 0)


def _chunk_table_problem(path: Path) -> str | None:
    """Why the chunk (offset) table of a single-part file does not fit the file, or None.

    Every offset of the full-resolution level (the one ringlight reads; writers may leave the
    other levels of a mip-map unwritten) must point past the table and inside the file, and the
    chunk at the largest of them must end within the file: a truncated file fails this, as does a
    zeroed table.
    Multi-part and deep files, unknown compressions and headers over the limit are not checked
    here (the library checks them as it decodes).
    """
    with _open_regular(path) as handle:
        size = os.fstat(handle.fileno()).st_size
        head = handle.read(2**16)
        version = int.from_bytes(head[4:8], "little")
        if version & (_DEEP | _MULTIPART):
            return None
        try:
            parsed = _attributes(head, size)
            if parsed is None:  # a long header: read on, up to the limit
                head += handle.read(_MAX_HEADER_BYTES - len(head))
                parsed = _attributes(head, size)
            if parsed is None:
                return None
            attributes, table_start = parsed
            chunks = _chunk_count(attributes, bool(version & _TILED))
        except ValueError as problem:
            return str(problem)
        if chunks is None:
            return None
        entries, first = chunks
        table_end = table_start + 8 * entries
        if table_end > size:
            return f"the file ends at byte {size}, inside its table of {entries} chunk offsets"
        handle.seek(table_start)
        offsets = np.frombuffer(handle.read(8 * first), "<u8")
        if len(offsets) != first:
            return "the file changed while it was read"
        if offsets.min() < table_end or offsets.max() >= size:
            return "a chunk offset points outside the file's data"
        last = int(offsets.max())
        prefix = 20 if version & _TILED else 8  # tile: x, y, level x, level y; scanline: y
        handle.seek(last)
        chunk_head = handle.read(prefix)
    if len(chunk_head) < prefix:
        return f"the file ends at byte {size}, inside its last chunk"
    data_size = int.from_bytes(chunk_head[prefix - 4:], "little", signed=True)
    if data_size < 0 or last + prefix + data_size > size:
        return f"the file ends at byte {size}, before the end of its last chunk"
    return None


def read_exr_header(path: str | os.PathLike) -> ExrHeader:
    """The size and channels of an EXR file, from its header alone.

    Raises
    ------
    DatasetError
        Naming the file: missing, not a regular file, not an OpenEXR file, a damaged header, a
        deep (per-sample) file, an empty data window or one over :data:`MAX_PIXELS`.
    """
    path = Path(path)
    _check_magic(path)
    try:
        with _quiet_library(), OpenEXR.File(str(path), header_only=True) as exr:
            header = exr.header()
            low, high = header["dataWindow"]
            channels = list(header.get("channels", []))
            names = tuple(str(channel.name) for channel in channels)
            subsampled = tuple(str(channel.name) for channel in channels
                               if channel.xSampling != 1 or channel.ySampling != 1)
    except Exception as error:  # noqa: BLE001 - OpenEXR raises RuntimeError/ValueError/KeyError for damaged data
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({_first_line(error)})") from None
    if "deep" in str(header.get("type", "")).lower():
        raise DatasetError(f"{path}: deep (per-sample) OpenEXR files are not supported")
    # Python ints: a hostile window cannot overflow.
    height, width = int(high[1]) - int(low[1]) + 1, int(high[0]) - int(low[0]) + 1
    if height <= 0 or width <= 0:
        raise DatasetError(f"{path}: empty data window {height} x {width}")
    if height * width > MAX_PIXELS:
        raise DatasetError(f"{path}: the header says {height} x {width} pixels, over the "
                           f"{MAX_PIXELS / 2**20:.0f} megapixels ringlight decodes")
    return ExrHeader(height, width, names, subsampled)


def exr_size(path: str | os.PathLike) -> tuple[int, int]:
    """Return ``(height, width)`` of an EXR file from its header alone (see :func:`read_exr_header`)."""
    header = read_exr_header(path)
    return header.height, header.width


def check_exr(path: str | os.PathLike, names: tuple[str, ...],
              expected_shape: tuple[int, int] | None = None, what: str = "image",
              size_of: str | None = None) -> ExrHeader:
    """Check everything about an EXR file that can be known without decoding its pixels.

    Parameters
    ----------
    path
        The EXR file.
    names
        Channels it must hold, e.g. ``("R", "G", "B")``.
    expected_shape
        ``(height, width)`` in pixels it must have, or None for any size.
    what
        What the file is, for the message (``"frame"``, ``"dark frame"``, ...).
    size_of
        What ``expected_shape`` is the size of (``"the grid"``), for the message.

    Returns
    -------
    The file's :class:`ExrHeader`.

    Raises
    ------
    DatasetError
        One line naming the file: any problem of :func:`read_exr_header`, a size other than
        ``expected_shape``, a missing or subsampled channel, more channel data than
        :data:`MAX_DECODED_BYTES`, or a chunk table that does not fit the file (truncation).
    """
    path = Path(path)
    header = read_exr_header(path)
    if expected_shape is not None and (header.height, header.width) != tuple(expected_shape):
        raise DatasetError(f"{path}: {what} is {header.height} x {header.width}, "
                           f"expected {expected_shape[0]} x {expected_shape[1]}"
                           + (f" (the size of {size_of})" if size_of else ""))
    missing = [name for name in names if name not in header.channels]
    if missing:
        found = ", ".join(sorted(header.channels)) or "none"
        raise DatasetError(f"{path}: missing channel(s) {', '.join(missing)} (found: {found})")
    if subsampled := [name for name in names if name in header.subsampled]:
        raise DatasetError(f"{path}: channel(s) {', '.join(subsampled)} are subsampled; "
                           "ringlight reads full-resolution channels only")
    decoded = 4 * header.height * header.width * len(header.channels)
    if decoded > MAX_DECODED_BYTES:
        raise DatasetError(f"{path}: its {len(header.channels)} channels would decode to "
                           f"{decoded / 2**30:.1f} GiB, over the {MAX_DECODED_BYTES / 2**30:.0f} GiB "
                           "ringlight decodes")
    try:
        problem = _chunk_table_problem(path)
    except OSError as error:
        raise DatasetError(f"{path}: cannot be read ({error.strerror or error})") from None
    if problem:
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({problem})")
    return header


def read_exr_channels(path: str | os.PathLike, names: tuple[str, ...],
                      expected_shape: tuple[int, int] | None = None, what: str = "image",
                      size_of: str | None = None) -> np.ndarray:
    """Read the named channels of an EXR file.

    Parameters
    ----------
    path
        The EXR file.
    names
        Channel names to read, in the order wanted, e.g. ``("R", "G", "B")``.
    expected_shape
        ``(height, width)`` the image must have (checked in the header, before decoding).
    what, size_of
        What the file is and what ``expected_shape`` is the size of, for messages.

    Returns
    -------
    (H, W, len(names)) float32 array.

    Raises
    ------
    DatasetError
        For every problem of :func:`check_exr` (all found before decoding), and for data the
        library cannot decode; the message names the file.
    """
    path = Path(path)
    header = check_exr(path, names, expected_shape, what, size_of)
    image = np.empty((header.height, header.width, len(names)), np.float32)
    try:
        with _quiet_library(), OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = exr.channels()
            for index, name in enumerate(names):
                plane = np.asarray(channels[name].pixels)
                if plane.shape != (header.height, header.width):
                    raise DatasetError(f"{path}: channel {name} differs in size from the header's data window")
                image[..., index] = plane
    except DatasetError:
        raise
    except Exception as error:  # noqa: BLE001 - OpenEXR raises RuntimeError/ValueError for damaged data
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({_first_line(error)})") from None
    return image


def _first_line(error: Exception) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0][:200]


def read_exr_rgb(path: str | os.PathLike, expected_shape: tuple[int, int] | None = None,
                 what: str = "image", size_of: str | None = None) -> np.ndarray:
    """Read the R, G, B channels of an EXR file as an (H, W, 3) float32 array (see
    :func:`read_exr_channels`)."""
    return read_exr_channels(path, ("R", "G", "B"), expected_shape, what, size_of)


def write_exr_channels(
    path: str | os.PathLike, channels: dict[str, np.ndarray], *, half: bool = False
) -> None:
    """Write 2-D arrays as the named channels of a ZIP-compressed scanline EXR.

    The file is written in place; callers that need atomicity write into a temporary folder.
    """
    dtype = np.float16 if half else np.float32
    pixels = {name: np.ascontiguousarray(plane, dtype=dtype) for name, plane in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, pixels) as exr:
        exr.write(str(path))


def write_exr_rgb(path: str | os.PathLike, image: np.ndarray, *, half: bool = False) -> None:
    """Write an (H, W, 3) image as R, G, B channels (float32, or half with ``half=True``)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {image.shape}")
    write_exr_channels(
        path, {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2]}, half=half
    )
