"""Reading and writing RGB OpenEXR images as float32 numpy arrays.

Images are (H, W, 3) float32 in channel order R, G, B. Half and float files are both read;
files are written as float (32-bit) unless ``half=True``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenEXR

from ..errors import DatasetError

_EXR_MAGIC = b"\x76\x2f\x31\x01"


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


def read_exr_channels(path: str | os.PathLike, names: tuple[str, ...]) -> np.ndarray:
    """Read the named channels of an EXR file.

    Parameters
    ----------
    path
        The EXR file.
    names
        Channel names to read, in the order wanted, e.g. ``("R", "G", "B")``.

    Returns
    -------
    (H, W, len(names)) float32 array.

    Raises
    ------
    DatasetError
        When the file is missing, unreadable, not an EXR, truncated or corrupt, or lacks one of
        the channels; the message names the file.
    """
    path = Path(path)
    _check_readable(path)
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
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
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({error})") from None
    if any(plane.ndim != 2 or plane.shape != planes[0].shape for plane in planes):
        raise DatasetError(f"{path}: channels {', '.join(names)} differ in size")
    return np.stack(planes, axis=-1)


def read_exr_rgb(path: str | os.PathLike) -> np.ndarray:
    """Read the R, G, B channels of an EXR file as an (H, W, 3) float32 array."""
    return read_exr_channels(path, ("R", "G", "B"))


def exr_size(path: str | os.PathLike) -> tuple[int, int]:
    """Return ``(height, width)`` of an EXR file from its header alone."""
    path = Path(path)
    _check_readable(path)
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            low, high = exr.header()["dataWindow"]
    except Exception as error:
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({error})") from None
    return int(high[1] - low[1] + 1), int(high[0] - low[0] + 1)


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
