"""The header of an OpenEXR frame file as docs/format/dataset.md, "Frame files" reads it: which part, which
channels, the image size, the window rule, chromaticities; refusals before any pixel is decoded.

Everything the OpenEXR library prints itself (warnings on stdout, errors on stderr) is swallowed
by :func:`quiet_library`, so that the user sees ringlight's one line and nothing else.
"""

from __future__ import annotations

import ctypes
import io
import os
import stat
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import OpenEXR

from ..errors import DatasetError
from .exr_chunks import MAX_PIXELS

RGB = ("R", "G", "B")
MONOCHROME = ("Y",)
EXR_MAGIC = b"\x76\x2f\x31\x01"
_LIBC = ctypes.CDLL(None) if os.name == "posix" else ctypes.cdll.msvcrt
"""The C library whose stdio buffers the OpenEXR library's C++ output passes through."""


@dataclass(frozen=True)
class ExrHeader:
    """What ringlight needs from the header of the part it reads.

    Attributes
    ----------
    height, width
        Image size in pixels (the data window, which equals the display window).
    channels
        Channel names of the part.
    subsampled
        Channels with an x or y sampling other than 1 (their planes are smaller than the image).
    part, parts
        Index of the part read and the number of parts in the file.
    chromaticities
        The part's ``chromaticities`` attribute (xy of R, G, B and white), or None.
    all_channels
        Channels of every part together (the library decodes them all in a multi-part file).
    """

    height: int
    width: int
    channels: tuple[str, ...]
    subsampled: tuple[str, ...] = ()
    part: int = 0
    parts: int = 1
    chromaticities: tuple[float, ...] | None = None
    all_channels: int = 0


class _Silence:
    """Descriptors 1 and 2 (and ``sys.stdout``, ``sys.stderr``) pointed at nothing while at least
    one thread is inside :func:`quiet_library`; ``depth`` counts them."""

    lock = threading.Lock()
    depth = 0
    saved: tuple[int, int] = (-1, -1)
    streams: tuple = (None, None)

    @classmethod
    def enter(cls) -> None:
        with cls.lock:
            if cls.depth == 0:
                for stream in (sys.stdout, sys.stderr):
                    if stream is not None:
                        stream.flush()
                cls.saved = (os.dup(1), os.dup(2))
                try:
                    null = os.open(os.devnull, os.O_WRONLY)
                    try:
                        os.dup2(null, 1)
                        os.dup2(null, 2)
                    finally:
                        os.close(null)
                except OSError:
                    cls._restore()
                    raise
                cls.streams = sys.stdout, sys.stderr
                sys.stdout, sys.stderr = io.StringIO(), io.StringIO()
            cls.depth += 1

    @classmethod
    def leave(cls) -> None:
        with cls.lock:
            cls.depth -= 1
            if cls.depth == 0:
                sys.stdout, sys.stderr = cls.streams
                cls._restore()

    @classmethod
    def _restore(cls) -> None:
        """Descriptors 1 and 2 back from the saved copies, which are closed."""
        _LIBC.fflush(None)
        os.dup2(cls.saved[0], 1)
        os.dup2(cls.saved[1], 2)
        for descriptor in cls.saved:
            os.close(descriptor)


@contextmanager
def quiet_library() -> Iterator[None]:
    """Silence what the OpenEXR library prints for damaged files: C++ output on file descriptors
    1 and 2 (C stdio buffers are flushed before they are restored) and its Python-level prints,
    which go to ``sys.stdout`` and ``sys.stderr``.

    File descriptors 1 and 2 are process-wide: the first thread in points them at /dev/null and
    the last one out restores them, so several threads decode at once (one at a time, the reader
    threads of an open decoded a frame each in turn). A Python thread printing meanwhile loses that
    output, which ringlight's workers never do (the command-line progress writes to a duplicate of
    descriptor 2).
    """
    _Silence.enter()
    try:
        yield
    finally:
        _Silence.leave()


def open_regular(path: Path):
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


def first_line(error: Exception) -> str:
    """The first line of an exception's message (at most 200 characters)."""
    return (str(error).strip().splitlines() or [type(error).__name__])[0][:200]


def _check_magic(path: Path) -> None:
    with open_regular(path) as handle:
        try:
            magic = handle.read(4)
        except OSError as error:
            raise DatasetError(f"{path}: cannot be read ({error.strerror or error})") from None
    if magic != EXR_MAGIC:
        raise DatasetError(f"{path}: not an OpenEXR file")


def _window(box) -> tuple[int, int, int, int]:
    """``(x_min, y_min, x_max, y_max)`` as Python ints (a hostile window cannot overflow)."""
    low, high = box
    return int(low[0]), int(low[1]), int(high[0]), int(high[1])


def _describe(window: tuple[int, int, int, int]) -> str:
    return f"({window[0]}, {window[1]})-({window[2]}, {window[3]})"


def _parts(path: Path) -> list[tuple[str, dict, tuple, bool]]:
    """``(name, header, channels, deep)`` of every part, from the headers alone."""
    try:
        with quiet_library(), OpenEXR.File(str(path), header_only=True) as exr:
            parts = [(str(part.name()), dict(part.header), tuple(part.header.get("channels", [])),
                      "deep" in str(part.type()).lower()) for part in exr.parts]
        for _, _, channels, _ in parts:
            for channel in channels:
                str(channel.name)  # decoded when first asked: a name that is not UTF-8 raises here
        return parts
    except Exception as error:  # noqa: BLE001 - OpenEXR raises RuntimeError/ValueError/KeyError for damaged data
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({first_line(error)})") from None


def _choose_part(path: Path, parts, names: tuple[str, ...] | None, part: str | None) -> int:
    """Index of the part to read (docs/format/dataset.md ``part``): the named one, the only one, or the one
    part holding ``names``."""
    listed = ", ".join(repr(name) for name, *_ in parts)
    if part is not None:
        matches = [index for index, (name, *_) in enumerate(parts) if name == part]
        if not matches:
            raise DatasetError(f"{path}: no part named {part!r} (parts: {listed})")
        return matches[0]
    if len(parts) == 1 or names is None:
        return 0
    holders = [index for index, (_, _, channels, _) in enumerate(parts)
               if set(names) <= {str(channel.name) for channel in channels}]
    if len(holders) > 1:
        raise DatasetError(f"{path}: {len(holders)} parts hold channels {', '.join(names)} "
                           f"({', '.join(repr(parts[i][0]) for i in holders)}); name one with 'part' in the manifest")
    return holders[0] if holders else 0


def frame_channels(path: str | os.PathLike, part: str | None = None) -> tuple[str, ...]:
    """The channels a frame is read with when the manifest names none (docs/format/dataset.md ``channels``):
    :data:`MONOCHROME` when the part read holds ``Y`` and no R, G, B, else :data:`RGB`."""
    path = Path(path)
    _check_magic(path)
    parts = _parts(path)
    if part is None and len(parts) > 1:
        candidates = [index for index, (_, _, channels, _) in enumerate(parts)
                      if {str(channel.name) for channel in channels} & {*RGB, *MONOCHROME}]
        index = candidates[0] if len(candidates) == 1 else 0
    else:
        index = _choose_part(path, parts, None, part)
    names = {str(channel.name) for channel in parts[index][2]}
    return MONOCHROME if "Y" in names and not names & set(RGB) else RGB


def read_exr_header(path: str | os.PathLike, names: tuple[str, ...] | None = None,
                    part: str | None = None, magic_checked: bool = False) -> ExrHeader:
    """The header of the part of an EXR file that holds ``names`` (see :func:`_choose_part`);
    ``magic_checked``: the caller has read the file's magic number from its open regular file
    (:func:`.exr.visit_exr`), which is not opened again for it.

    Raises
    ------
    DatasetError
        Naming the file: missing, not a regular file, not an OpenEXR file, a damaged header, no
        such part or several candidate parts, a deep (per-sample) part, a data window other than
        the display window (both named), an empty window or one over :data:`MAX_PIXELS`.
    """
    path = Path(path)
    if not magic_checked:
        _check_magic(path)
    parts = _parts(path)
    if not parts:
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file (no part)")
    index = _choose_part(path, parts, names, part)
    _, header, channels, _ = parts[index]
    if any(deep for *_, deep in parts):
        raise DatasetError(f"{path}: deep (per-sample) OpenEXR files are not supported; "
                           "ringlight reads flat scanline or tiled images")
    try:
        data = _window(header["dataWindow"])
        display = _window(header.get("displayWindow", header["dataWindow"]))
        chromaticities = header.get("chromaticities")
        chromaticities = None if chromaticities is None else tuple(float(v) for v in chromaticities)
        names_found = tuple(str(channel.name) for channel in channels)
        subsampled = tuple(str(channel.name) for channel in channels
                           if channel.xSampling != 1 or channel.ySampling != 1)
    except (KeyError, TypeError, ValueError, IndexError) as error:
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({first_line(error)})") from None
    if data != display:
        raise DatasetError(f"{path}: data window {_describe(data)} differs from display window "
                           f"{_describe(display)}; ringlight reads frames whose data window is their display window")
    height, width = data[3] - data[1] + 1, data[2] - data[0] + 1
    if height <= 0 or width <= 0:
        raise DatasetError(f"{path}: empty data window {height} x {width}")
    if height * width > MAX_PIXELS:
        raise DatasetError(f"{path}: the header says {height} x {width} pixels, over the "
                           f"{MAX_PIXELS / 2**20:.0f} megapixels ringlight decodes")
    if chromaticities is not None and len(chromaticities) != 8:
        chromaticities = None
    return ExrHeader(height, width, names_found, subsampled, index, len(parts), chromaticities,
                     sum(len(channels) for _, _, channels, _ in parts))
