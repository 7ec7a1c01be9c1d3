"""Decoding a small scanline OpenEXR frame from the bytes already read to check it.

The OpenEXR library costs about 60 us a file before its first pixel (it opens the file again,
reads its header into Python objects, sets up its buffers): for a 10 x 10 frame that is the whole
decode, and 100 000 such frames took 6 s of it. A file ringlight has read whole to check it
(:func:`.exr.visit_exr`) whose header has passed before (:mod:`.exr_seen`) and whose layout is the
simplest one (scanlines; no, ZIPS or ZIP compression; HALF or FLOAT channels, none subsampled; at
most :data:`SMALL_BYTES` of pixels) is decoded here from those bytes with zlib and numpy, as the
OpenEXR file layout specifies. Anything else, or anything unexpected in its chunks (a y that is
not the chunk's, a size that does not match, data zlib refuses), is left to the library
(:func:`decode_small` returns None), which then says what is wrong.

A run of such frames is decoded in one compiled call (:mod:`.frame_batch`), each frame by
:func:`_decode_frame`, which checks its chunk table as :func:`.exr_chunks.offsets_problem` does
and inflates its chunks with the zlib library's ``uncompress2`` called from compiled code
(:data:`NATIVE_INFLATE`; where that library cannot be loaded, frames are decoded one by one).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import struct
import zlib
from dataclasses import dataclass
from functools import lru_cache

import llvmlite.binding
import numba
import numpy as np

from .exr_chunks import ChunkLayout, _attributes, chunks_fit, int_at

SMALL_BYTES = 2**20
"""Most bytes of decoded pixels (all channels) of a file decoded here."""
_NONE, _ZIPS, _ZIP = 0, 2, 3
_LINES = {_NONE: 1, _ZIPS: 1, _ZIP: 16}
_SAMPLE = {1: np.dtype("<f2"), 2: np.dtype("<f4")}
"""Pixel types decoded here (HALF, FLOAT) and their samples."""
_TILED, _DEEP, _MULTIPART = 0x200, 0x800, 0x1000


@dataclass(frozen=True)
class SmallLayout:
    """What decoding a file of a given header takes: its data window's ``width``, ``height`` and
    top ``y_min``, the compression, scanlines per chunk, and the channels in file order as
    ``(name, sample dtype)``."""

    width: int
    height: int
    y_min: int
    compression: int
    lines: int
    channels: tuple[tuple[str, np.dtype], ...]

    @property
    def line_bytes(self) -> int:
        return self.width * sum(sample.itemsize for _, sample in self.channels)


def small_layout(header_bytes: bytes) -> SmallLayout | None:
    """The :class:`SmallLayout` of a single-part file whose header is ``header_bytes`` (from its
    start to its chunk table), or None when it is not one decoded here."""
    version = int.from_bytes(header_bytes[4:8], "little")
    if version & (_TILED | _DEEP | _MULTIPART):
        return None
    try:
        parsed = _attributes(header_bytes, len(header_bytes))
    except ValueError:
        return None
    if parsed is None:
        return None
    attributes = parsed[0]
    compression, window, chlist = (attributes.get(name) for name in ("compression", "dataWindow", "channels"))
    if compression is None or len(compression) != 1 or compression[0] not in _LINES or window is None \
            or len(window) != 16 or chlist is None:
        return None
    x_min, y_min, x_max, y_max = struct.unpack("<4i", window)
    channels, at = [], 0
    while at < len(chlist) and chlist[at] != 0:
        end = chlist.find(b"\0", at)
        if end < 0 or end + 17 > len(chlist):
            return None
        pixel_type, _, x_sampling, y_sampling = struct.unpack_from("<iB3xii", chlist, end + 1)
        if pixel_type not in _SAMPLE or x_sampling != 1 or y_sampling != 1:
            return None
        channels.append((chlist[at:end].decode("latin-1"), _SAMPLE[pixel_type]))
        at = end + 17
    layout = SmallLayout(x_max - x_min + 1, y_max - y_min + 1, y_min, compression[0], _LINES[compression[0]],
                         tuple(channels))
    if not channels or layout.width <= 0 or layout.height <= 0 or layout.height * layout.line_bytes > SMALL_BYTES:
        return None
    return layout


def decode_small(data: bytes, layout: SmallLayout, chunks: ChunkLayout, names: tuple[str, ...],
                 image: np.ndarray, first: int = 0) -> bool:
    """Write rows ``first .. first + len(image)`` of the channels ``names`` of the whole file
    ``data`` into ``image`` ((rows, width, len(names)) float32, HALF samples converted exactly) and
    return True; False when anything is not as :func:`small_layout` and the file layout say (the
    caller then decodes the file with the library, which overwrites what was written)."""
    picked = _picked(layout, tuple(names))
    if picked is None or chunks.tiled or chunks.first != -(-layout.height // layout.lines):
        return False
    table = data[chunks.table_start:chunks.table_start + 8 * chunks.first]
    if len(table) != 8 * chunks.first:
        return False
    stop = first + image.shape[0]
    for index, offset in enumerate(struct.unpack(f"<{chunks.first}Q", table)):
        top = index * layout.lines
        rows = min(layout.lines, layout.height - top)
        if top + rows <= first or top >= stop:
            continue  # no row of the band
        if offset + 8 > len(data):
            return False
        y, size = struct.unpack_from("<ii", data, offset)
        raw_size = rows * layout.line_bytes
        if y != layout.y_min + top or size < 0 or offset + 8 + size > len(data):
            return False
        payload = data[offset + 8:offset + 8 + size]
        zipped = size != raw_size  # else stored as it is: no compression, or none that made it smaller
        if zipped:
            if layout.compression == _NONE:
                return False
            try:
                inflater = zlib.decompressobj()
                payload = inflater.decompress(payload, raw_size)
            except zlib.error:
                return False
            if len(payload) != raw_size or not inflater.eof or inflater.unconsumed_tail:
                return False
        _unpack(np.frombuffer(bytearray(payload), np.uint8), zipped, rows, top - first, layout.width, *picked,
                _HALF_TO_FLOAT, image)
    return True


@lru_cache(maxsize=64)
def _picked(layout: SmallLayout, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """For each channel of the file that is one of ``names``: its first byte within a scanline,
    whether it is HALF, and its index in ``names``; None when one of ``names`` is not in it."""
    starts, halves, targets, at = [], [], [], 0
    for name, sample in layout.channels:
        if name in names:
            starts.append(at)
            halves.append(sample.itemsize == 2)
            targets.append(names.index(name))
        at += layout.width * sample.itemsize
    if sorted(targets) != list(range(len(names))):
        return None
    return np.array(starts, np.int64), np.array(halves, np.bool_), np.array(targets, np.int64)


_HALF_TO_FLOAT = np.arange(2**16, dtype=np.uint32).astype(np.uint16).view(np.float16).astype(np.float32)
"""The float32 value of every half-float bit pattern (numpy's conversion, exact)."""


@numba.njit(cache=True, nogil=True)
def _unpack(raw, zipped, rows, top, width, starts, halves, targets, half_to_float, image):  # pragma: no cover
    """Scanlines ``top .. top + rows`` (in ``image``'s rows; those outside it skipped) from one
    chunk's bytes ``raw``: with ``zipped``, zlib's output, in which the format's predictor is undone
    in place (each byte the previous one's plus its delta, less 128, modulo 256: ``raw`` must be
    writable) and whose two halves hold the even and the odd bytes of the scanlines. Each
    scanline holds every channel's samples in turn, little-endian; the picked ones go to
    ``image[y, x, targets[c]]`` as float32."""
    count = raw.size
    if zipped:
        previous = np.int64(raw[0])
        for i in range(1, count):
            previous = (previous + np.int64(raw[i]) - 128) & 0xFF
            raw[i] = previous
    # Samples start at even bytes (every channel's row is width x 2 or 4 bytes), so a sample's even
    # bytes are read from the first half of zlib's output and its odd ones from the second, in
    # place: a pair of bytes 2 apart in the scanline is 1 apart there (2 apart as stored).
    half = count // 2 if zipped else 1
    pair = 1 if zipped else 2
    bits = np.empty(1, np.uint32)
    as_float = bits.view(np.float32)
    line_bytes = count // rows
    for row in range(rows):
        y = top + row
        if y < 0 or y >= image.shape[0]:
            continue
        for c in range(starts.size):
            at = row * line_bytes + starts[c]
            even = at // 2 if zipped else at
            odd = even + half
            k = targets[c]
            if halves[c]:
                for x in range(width):
                    image[y, x, k] = half_to_float[np.int64(raw[even + pair * x]) | (np.int64(raw[odd + pair * x]) << 8)]
            else:
                for x in range(width):
                    b = 2 * pair * x
                    bits[0] = (np.uint32(raw[even + b]) | (np.uint32(raw[odd + b]) << np.uint32(8))
                               | (np.uint32(raw[even + b + pair]) << np.uint32(16))
                               | (np.uint32(raw[odd + b + pair]) << np.uint32(24)))
                    image[y, x, k] = as_float[0]


def _load_inflate() -> bool:
    """Make zlib's ``uncompress2`` (zlib 1.2.9 on) callable from compiled code; False when the
    library cannot be found or loaded. Its usual names are tried first: ``find_library`` runs
    ``ldconfig``, 40 ms at every start."""
    for name in ("libz.so.1", "libz.1.dylib", None):
        name = name or ctypes.util.find_library("z")
        if name is None:
            return False
        try:
            ctypes.CDLL(name).uncompress2  # noqa: B018 - an older zlib lacks it
            llvmlite.binding.load_library_permanently(name)
        except (OSError, AttributeError, RuntimeError):
            continue
        return True
    return False


NATIVE_INFLATE = _load_inflate()
"""Whether :func:`_decode_frame` can inflate ZIP and ZIPS chunks (zlib's ``uncompress2``)."""
LENGTH_TYPE = np.uint64 if ctypes.sizeof(ctypes.c_ulong) == 8 else np.uint32
"""zlib's ``uLong``: the type of the two lengths ``uncompress2`` reads and writes."""
_uncompress2 = numba.types.ExternalFunction(
    "uncompress2", numba.types.intc(numba.types.voidptr, numba.types.voidptr, numba.types.voidptr,
                                    numba.types.voidptr))
LAYOUT_FIELDS = 8
"""Length of the int64 array :func:`layout_array` makes of a :class:`SmallLayout` for compiled code."""


def layout_array(layout: SmallLayout, table_start: int, first: int) -> np.ndarray:
    """(LAYOUT_FIELDS,) int64: what :func:`_decode_frame` needs of a file's layout and chunk table
    (its start), and ``first``, the first row decoded."""
    return np.array([table_start, -(-layout.height // layout.lines), layout.lines, layout.y_min, layout.height,
                     layout.line_bytes, layout.compression, first], np.int64)


@numba.njit(cache=True, nogil=True)
def _decode_frame(data, start, size, layout, width, starts, halves, targets, half_to_float, image,
                  lengths, raw):  # pragma: no cover - compiled
    """:func:`decode_small` of the file ``data[start:start + size]`` compiled: rows ``layout[7] ..
    layout[7] + len(image)`` of the picked channels into ``image`` ((rows, width, C) float32);
    ``layout`` from :func:`layout_array`; ``lengths`` (2,) :data:`LENGTH_TYPE` scratch for zlib and
    ``raw`` (``layout[2] * layout[5]``,) uint8 (lines x line bytes) for a chunk's bytes (one for a run
    of frames: an array made for each chunk cost about as much as undoing its predictor).
    Returns False when the chunk table does not fit the file (:func:`chunks_fit`) or anything is
    not as :func:`decode_small` requires; the frame is then read alone, which says why."""
    table_start, chunks, lines, y_min, height, line_bytes, compression, first = (
        layout[0], layout[1], layout[2], layout[3], layout[4], layout[5], layout[6], layout[7])
    if not chunks_fit(data, start, size, table_start, chunks):
        return False
    stop = first + image.shape[0]
    for index in range(chunks):
        offset = int_at(data, start + table_start + 8 * index, 8)
        top = index * lines
        rows = min(lines, height - top)
        if top + rows <= first or top >= stop:
            continue  # no row of the band
        y = int_at(data, start + offset, 4)
        length = int_at(data, start + offset + 4, 4)
        raw_size = rows * line_bytes
        if y != y_min + top or length < 0 or offset + 8 + length > size:
            return False
        at = start + offset + 8
        chunk = raw[:raw_size]
        if length == raw_size:  # stored as it is: no compression, or none that made it smaller
            # Copied: _unpack undoes the predictor in place, and numba refuses its writes to a
            # read-only ``data`` when typing it, whichever branch runs.
            chunk[:] = data[at:at + length]
            _unpack(chunk, False, rows, top - first, width, starts, halves, targets, half_to_float, image)
            continue
        if compression == _NONE:
            return False
        lengths[0] = raw_size
        lengths[1] = length
        # Z_OK only for a stream that ends within its bytes, inflating to at most raw_size bytes.
        if _uncompress2(chunk.ctypes.data, lengths[0:].ctypes.data, data[at:].ctypes.data,
                        lengths[1:].ctypes.data) != 0 or lengths[0] != raw_size:
            return False
        _unpack(chunk, True, rows, top - first, width, starts, halves, targets, half_to_float, image)
    return True
