"""Reading and writing OpenEXR images as float32 numpy arrays.

Images are (H, W, C) float32 in the order of the channel names asked for (R, G, B for colour
frames, Y for a monochrome camera); HALF, FLOAT and UINT channels are all read, scanline or tiled
(the full-resolution level), any compression the library reads. Files are written as float
(32-bit) unless ``half=True``.

Every read checks the header first (:func:`check_exr`): the part, the size against what the
caller expects, the window rule, the channels, the chromaticities against the dataset's
colourspace, and that the file's chunk table fits in the file, so that a small damaged or hostile
file is refused before anything is decoded. Only the channels asked for are decoded from a
single-part file; the library decodes every channel of a multi-part file. Whole files of just the
channels asked for (every frame a camera or the writer makes) decode without holding the GIL.
"""

from __future__ import annotations

import json
import os
import stat
import threading
from pathlib import Path

import Imath
import numba
import numpy as np
import OpenEXR

from ..colourspaces import chromaticities_differ, colourspace_chromaticities, describe_chromaticities
from ..errors import DatasetError
from .exr_chunks import HEAD_BYTES, ChunkLayout, chunk_layout, offsets_problem
from .exr_header import EXR_MAGIC, ExrHeader, first_line, quiet_library, read_exr_header
from .exr_seen import HeaderCache, PassedHeader
from .exr_small import decode_small, small_layout

MAX_DECODED_BYTES = 2**30
"""Largest total of the channels a read decodes (4 bytes a value)."""
_FLOAT = Imath.PixelType(Imath.PixelType.FLOAT)
_SELECTING = threading.Lock()
"""One decode at a time in the library's selecting reader, which holds the GIL: two threads in it
at once, with the library's own threads on, stalled each other (a band of half the rows of every
512 px frame: 24.6 s where one thread took 4.2 s)."""
_HALF_TO_FLOAT = np.arange(2**16, dtype=np.uint32).astype(np.uint16).view(np.float16).astype(np.float32)
"""The float32 value of every half-float bit pattern (numpy's conversion, exact)."""


def check_exr(path: str | os.PathLike, names: tuple[str, ...],
              expected_shape: tuple[int, int] | None = None, what: str = "image",
              size_of: str | None = None, part: str | None = None,
              colorspace: str | None = None, headers: HeaderCache | None = None) -> ExrHeader:
    """Check everything about an EXR file that can be known without decoding its pixels.

    Parameters
    ----------
    path
        The EXR file.
    names
        Channels it must hold, e.g. ``("R", "G", "B")``, ``("camera.R", ...)`` or ``("Y",)``.
    expected_shape
        ``(height, width)`` in pixels it must have, or None for any size.
    what
        What the file is, for the message (``"frame"``, ``"dark frame"``, ...).
    size_of
        What ``expected_shape`` is the size of (``"the grid"``), for the message.
    part
        Name of the part to read in a multi-part file (None: the one part holding ``names``).
    colorspace
        The dataset's colourspace name: a ``chromaticities`` attribute that differs from it by
        more than 1e-3 is refused. None: not checked (mappings, ground truth of other spaces).
    headers
        Headers already checked in this pass (:mod:`.exr_seen`): a file whose header is one of
        them is not read by the library again.

    Returns
    -------
    The header of the part read (:class:`ExrHeader`).

    Raises
    ------
    DatasetError
        One line naming the file: any problem of :func:`read_exr_header`, a size other than
        ``expected_shape``, a missing or subsampled channel, chromaticities of another colourspace
        (both named), more channel data than :data:`MAX_DECODED_BYTES`, or a chunk table that does
        not fit the file (truncation).
    """
    return visit_exr(path, names, expected_shape, what, size_of, part, colorspace, headers)[0]


def visit_exr(path: str | os.PathLike, names: tuple[str, ...],
              expected_shape: tuple[int, int] | None = None, what: str = "image",
              size_of: str | None = None, part: str | None = None, colorspace: str | None = None,
              headers: HeaderCache | None = None, whole_up_to: int = 0,
              descriptor: int | None = None) -> tuple[ExrHeader, bytes | None, PassedHeader | None]:
    """:func:`check_exr` in one opening of the file, which also returns the file's bytes when it
    has at most ``whole_up_to`` of them (else None), so that it is decoded without opening it
    again, and the header's entry in ``headers`` (None without one). The library reads the header only when ``headers`` does not hold it (it then opens
    the file itself). ``descriptor``: the regular file ``path`` already open for reading
    (:meth:`.file_paths.FileResolver.open`), which is closed when done."""
    location = os.fspath(path)
    # Unbuffered: a buffered reader's own 8 KiB buffer and set-up cost more than a small file.
    with open(_open_file(location) if descriptor is None else descriptor, "rb", buffering=0) as handle:
        try:
            size = os.fstat(handle.fileno()).st_size
            head = handle.read(size + 1 if size <= whole_up_to else min(size + 1, HEAD_BYTES))
            if head[:4] != EXR_MAGIC:
                raise DatasetError(f"{Path(location)}: not an OpenEXR file")
            request = (names, None if expected_shape is None else tuple(expected_shape), part, colorspace)
            passed = headers.find(head, request) if headers is not None else None
            if passed is not None:
                header, layout = passed.header, passed.layout
            else:
                header = read_exr_header(Path(location), names, part, magic_checked=True)
                _check_header(Path(location), header, names, expected_shape, what, size_of, colorspace)
                if headers is not None:
                    headers.library_reads += 1
                layout, head = chunk_layout(handle, head, size)
            problem = offsets_problem(handle, head, size, layout) if isinstance(layout, ChunkLayout) else layout
        except OSError as error:
            raise DatasetError(f"{Path(location)}: cannot be read ({error.strerror or error})") from None
    if problem:
        raise DatasetError(f"{Path(location)}: truncated or corrupt OpenEXR file ({problem})")
    if passed is None and headers is not None and isinstance(layout, ChunkLayout):
        passed = PassedHeader(head[:layout.table_start], request, header, layout,
                              small_layout(head[:layout.table_start]))
        headers.add(passed)
    return header, (head if len(head) == size else None), passed


def _open_file(location: str) -> int:
    """A descriptor of the regular file at ``location`` opened for reading
    (:func:`.exr_header.open_regular`), named as a Path in its errors."""
    try:
        descriptor = os.open(location, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO must not block
    except FileNotFoundError:
        raise DatasetError(f"{Path(location)}: file not found") from None
    except OSError as error:
        raise DatasetError(f"{Path(location)}: cannot be read ({error.strerror or error})") from None
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        raise DatasetError(f"{Path(location)}: not a file")
    return descriptor


def _check_header(path: Path, header: ExrHeader, names: tuple[str, ...], expected_shape, what: str,
                  size_of: str | None, colorspace: str | None) -> None:
    """The checks of :func:`check_exr` that its header alone decides."""
    if expected_shape is not None and (header.height, header.width) != tuple(expected_shape):
        raise DatasetError(f"{path}: {what} is {header.height} x {header.width}, "
                           f"expected {expected_shape[0]} x {expected_shape[1]}"
                           + (f" (the size of {size_of})" if size_of else ""))
    missing = [name for name in names if name not in header.channels]
    if missing:
        found = ", ".join(sorted(header.channels)) or "none"
        prefixed = [next((found for found in sorted(header.channels) if found.endswith("." + name)), None)
                    for name in names]
        hint = (f"; read them with \"channels\": {json.dumps(prefixed)} in the manifest"
                if what in ("frame", "dark frame") and all(prefixed) else "")
        raise DatasetError(f"{path}: missing channel(s) {', '.join(missing)} (found: {found}){hint}")
    if subsampled := [name for name in names if name in header.subsampled]:
        raise DatasetError(f"{path}: channel(s) {', '.join(subsampled)} are subsampled; "
                           "ringlight reads full-resolution channels only")
    if (colorspace is not None and header.chromaticities is not None
            and chromaticities_differ(header.chromaticities, colorspace)):
        raise DatasetError(
            f"{path}: chromaticities {describe_chromaticities(header.chromaticities)} differ from the "
            f"dataset's colorspace {colorspace} ({describe_chromaticities(colourspace_chromaticities(colorspace))}); "
            "write the file's chromaticities into 'colorspace' to read it")
    decoded_channels = len(names) if header.parts == 1 else header.all_channels
    decoded = 4 * header.height * header.width * decoded_channels
    if decoded > MAX_DECODED_BYTES:
        raise DatasetError(f"{path}: its {decoded_channels} decoded channels would take "
                           f"{decoded / 2**30:.1f} GiB, over the {MAX_DECODED_BYTES / 2**30:.0f} GiB "
                           "ringlight decodes")


def read_exr_channels(path: str | os.PathLike, names: tuple[str, ...],
                      expected_shape: tuple[int, int] | None = None, what: str = "image",
                      size_of: str | None = None, part: str | None = None,
                      colorspace: str | None = None, rows: tuple[int, int] | None = None,
                      headers: HeaderCache | None = None, descriptor: int | None = None) -> np.ndarray:
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
    part, colorspace, headers
        See :func:`check_exr`.
    descriptor
        The file already open for reading (see :func:`visit_exr`).
    rows
        ``(first, stop)``: read only these rows of the image (a single-part file decodes only
        the chunks holding them; a multi-part file is decoded whole).

    Returns
    -------
    (H, W, len(names)) float32 array (H: the rows read): HALF and FLOAT values exactly, UINT
    values rounded to float32.

    Raises
    ------
    DatasetError
        For every problem of :func:`check_exr` (all found before decoding), and for data the
        library cannot decode; the message names the file.
    """
    header, data, passed = visit_exr(path, names, expected_shape, what, size_of, part, colorspace, headers,
                                     HEAD_BYTES if headers is not None else 0, descriptor)
    first, stop = rows if rows is not None else (0, header.height)
    if not 0 <= first < stop <= header.height:
        raise ValueError(f"rows {first}..{stop} outside the image's {header.height}")
    height = stop - first
    image = np.empty((height, header.width, len(names)), np.float32)
    if data is not None and passed is not None and passed.small is not None \
            and decode_small(data, passed.small, passed.layout, names, image, first):
        return image  # a small file decoded from the bytes its check read (module exr_small)
    path = Path(path)
    try:
        with quiet_library():
            if not whole_file_reader(header, names, height):
                with _SELECTING:
                    _read_selected(path, names, first, stop, image)
            else:
                with OpenEXR.File(str(path), separate_channels=True) as exr:
                    if len(exr.parts) != header.parts:  # the library skips a part it cannot decode
                        if header.parts == 1:  # the selecting reader says why
                            with _SELECTING:
                                _read_selected(path, names, first, stop, image)
                        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file (a part cannot be decoded)")
                    channels = exr.parts[header.part].channels
                    for index, name in enumerate(names):
                        plane = np.asarray(channels[name].pixels)
                        if plane.shape != (header.height, header.width):
                            raise DatasetError(f"{path}: channel {name} differs in size from the header's data window")
                        if plane.dtype == np.float16:  # numpy's own conversion takes 5 times as long
                            _put_half(plane[first:stop].view(np.uint16), _HALF_TO_FLOAT, image, index)
                        else:
                            image[..., index] = plane[first:stop]
    except DatasetError:
        raise
    except Exception as error:  # noqa: BLE001 - OpenEXR raises RuntimeError/ValueError for damaged data
        raise DatasetError(f"{path}: truncated or corrupt OpenEXR file ({first_line(error)})") from None
    return image


def whole_file_reader(header: ExrHeader, names: tuple[str, ...], rows: int | None = None) -> bool:
    """Whether :func:`read_exr_channels` decodes ``rows`` rows (None: all) of the named channels
    of a file with this header with the library's reader of whole files, which releases the GIL,
    so that frames decode side by side in threads: a multi-part file, or all rows of a file whose
    channels are those asked for. Otherwise the channel-selecting reader, which holds the GIL,
    decodes only the rows and channels asked for (a band, or a file with more channels: RGBA,
    render layers)."""
    every_row = rows is None or rows == header.height
    return header.parts > 1 or (every_row and set(header.channels) == set(names))


def _read_selected(path: Path, names: tuple[str, ...], first: int, stop: int, image: np.ndarray) -> None:
    """Decode rows ``first .. stop`` of the named channels of a single-part file into ``image``
    ((stop - first, W, len(names)) float32) with the library's channel-selecting reader."""
    exr = OpenEXR.InputFile(str(path))
    try:
        top = exr.header()["dataWindow"].min.y
        planes = exr.channels(list(names), _FLOAT, top + first, top + stop - 1)
    finally:
        exr.close()
    for index, plane in enumerate(planes):
        if len(plane) != image.shape[0] * image.shape[1] * 4:
            raise DatasetError(f"{path}: channel {names[index]} differs in size from the header's data window")
        image[..., index] = np.frombuffer(plane, np.float32).reshape(image.shape[:2])


@numba.njit(cache=True, nogil=True)
def _put_half(bits, table, image, channel):  # pragma: no cover - compiled
    """``image[..., channel] = table[bits]``: a (rows, W) plane of half floats, as their uint16
    bits, into an (rows, W, C) float32 image (0.065 against numpy's 0.33 ms for 256 x 256 x 3)."""
    for y in range(bits.shape[0]):
        for x in range(bits.shape[1]):
            image[y, x, channel] = table[bits[y, x]]


def read_exr_rgb(path: str | os.PathLike, expected_shape: tuple[int, int] | None = None,
                 what: str = "image", size_of: str | None = None) -> np.ndarray:
    """Read the R, G, B channels of an EXR file as an (H, W, 3) float32 array (see
    :func:`read_exr_channels`)."""
    return read_exr_channels(path, ("R", "G", "B"), expected_shape, what, size_of)


def write_exr_channels(
    path: str | os.PathLike, channels: dict[str, np.ndarray], *, half: bool = False,
    attributes: dict[str, str | float] | None = None,
) -> None:
    """Write 2-D arrays as the named channels of a ZIP-compressed scanline EXR, with
    ``attributes`` (str or float values) added to its header.

    The file is written in place; callers that need atomicity write into a temporary folder.
    The file is read back and must hold the pixels written: the library reports no failed write
    (a full disk left a torn file and no error), so a torn file raises
    :class:`~ringlight.core.atomic.OutputError` naming ``path``.
    """
    dtype = np.float16 if half else np.float32
    pixels = {name: np.ascontiguousarray(plane, dtype=dtype) for name, plane in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attributes or {})
    with OpenEXR.File(header, dict(pixels)) as exr:  # the library turns the dict's arrays into Channels
        exr.write(str(path))
    if not _holds(path, pixels):
        from ..atomic import OutputError

        raise OutputError(f"{path}: the EXR file could not be written whole (is the disk full?)")


def _holds(path: str | os.PathLike, pixels: dict[str, np.ndarray]) -> bool:
    """True when the EXR file at ``path`` decodes to exactly ``pixels`` (bit for bit: NaN too)."""
    try:
        with quiet_library(), OpenEXR.File(str(path), separate_channels=True) as exr:
            found = exr.channels()
            return found.keys() == pixels.keys() and all(
                found[name].pixels.dtype == plane.dtype and found[name].pixels.tobytes() == plane.tobytes()
                for name, plane in pixels.items())
    except Exception:  # the library's error for a torn file: RuntimeError, or worse
        return False


def write_exr_rgb(path: str | os.PathLike, image: np.ndarray, *, half: bool = False) -> None:
    """Write an (H, W, 3) image as R, G, B channels (float32, or half with ``half=True``)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {image.shape}")
    write_exr_channels(
        path, {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2]}, half=half
    )
