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
from .exr_chunks import MAX_PIXELS, chunk_table_problem

_EXR_MAGIC = b"\x76\x2f\x31\x01"
MAX_DECODED_BYTES = 2**30
"""Largest total of all channels of a file (the library decodes every channel of a part)."""

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
        with _open_regular(path) as handle:
            problem = chunk_table_problem(handle, os.fstat(handle.fileno()).st_size)
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
