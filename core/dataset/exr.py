"""Reading and writing RGB OpenEXR images as float32 numpy arrays.

Images are (H, W, 3) float32 in channel order R, G, B. Half and float files are both read;
files are written as float (32-bit) unless ``half=True``.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR

from ..errors import DatasetError

_EXR_MAGIC = b"\x76\x2f\x31\x01"
MAX_PIXELS = 2**26
"""Largest image (pixels) decoded: 67 megapixels, beyond any camera a rig uses. The size is
checked in the header before anything is decoded, so a small file cannot claim gigabytes."""

_QUIET_LOCK = threading.Lock()


@contextmanager
def _quiet_library() -> Iterator[None]:
    """Silence what the OpenEXR C++ library itself prints on stdout and stderr for damaged files,
    so that the user sees ringlight's one line and nothing else."""
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


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise DatasetError(f"{path}: file not found")
    if not path.is_file():
        raise DatasetError(f"{path}: not a file")
    try:
        with open(path, "rb") as handle:
            magic = handle.read(4)
    except OSError as error:
        raise DatasetError(f"{path}: cannot be read ({error.strerror})") from None
    if magic != _EXR_MAGIC:
        raise DatasetError(f"{path}: not an OpenEXR file")


def read_exr_channels(path: str | os.PathLike, names: tuple[str, ...],
                      expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read the named channels of an EXR file.

    Parameters
    ----------
    path
        The EXR file.
    names
        Channel names to read, in the order wanted, e.g. ``("R", "G", "B")``.
    expected_shape
        ``(height, width)`` the image must have (checked in the header, before decoding).

    Returns
    -------
    (H, W, len(names)) float32 array.

    Raises
    ------
    DatasetError
        When the file is missing, unreadable, not an EXR, truncated or corrupt, larger than
        :data:`MAX_PIXELS` or than ``expected_shape``, or lacks one of the channels; the message
        names the file.
    """
    path = Path(path)
    height, width = exr_size(path)
    if expected_shape is not None and (height, width) != tuple(expected_shape):
        raise DatasetError(f"{path}: image is {height} x {width}, expected {expected_shape[0]} x {expected_shape[1]}")
    try:
        with _quiet_library(), OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = exr.channels()
            missing = [name for name in names if name not in channels]
            if missing:
                found = ", ".join(sorted(channels)) or "none"
                raise DatasetError(
                    f"{path}: missing channel(s) {', '.join(missing)} (found: {found})"
                )
            planes = [np.asarray(channels[name].pixels, dtype=np.float32) for name in names]
    except DatasetError:
        raise
    except Exception as error:  # OpenEXR raises RuntimeError/ValueError for damaged data
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({_first_line(error)})") from None
    if any(plane.ndim != 2 or plane.shape != (height, width) for plane in planes):
        raise DatasetError(f"{path}: channels {', '.join(names)} differ in size from the header's data window")
    return np.stack(planes, axis=-1)


def _first_line(error: Exception) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0][:200]


def read_exr_rgb(path: str | os.PathLike, expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read the R, G, B channels of an EXR file as an (H, W, 3) float32 array."""
    return read_exr_channels(path, ("R", "G", "B"), expected_shape)


def exr_size(path: str | os.PathLike) -> tuple[int, int]:
    """Return ``(height, width)`` of an EXR file from its header alone.

    Raises :class:`DatasetError` for a missing, non-EXR or damaged file, a deep (per-sample)
    file, and an image over :data:`MAX_PIXELS`.
    """
    path = Path(path)
    _check_readable(path)
    try:
        with _quiet_library(), OpenEXR.File(str(path), header_only=True) as exr:
            header = exr.header()
            low, high = header["dataWindow"]
    except Exception as error:
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({_first_line(error)})") from None
    if "deep" in str(header.get("type", "")).lower():
        raise DatasetError(f"{path}: deep (per-sample) OpenEXR files are not supported")
    height, width = int(high[1]) - int(low[1]) + 1, int(high[0]) - int(low[0]) + 1
    if height <= 0 or width <= 0:
        raise DatasetError(f"{path}: empty data window {height} x {width}")
    if height * width > MAX_PIXELS:
        raise DatasetError(f"{path}: the header says {height} x {width} pixels, over the "
                           f"{MAX_PIXELS / 2**20:.0f} megapixels ringlight decodes")
    return height, width


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
