"""The chunk (offset) table of a single-part OpenEXR file, checked against the file's length.

A byte-level reading of the header (OpenEXR file layout, version 2): enough to find where the
chunk table starts and how many entries it has, so that a truncated or zeroed file is refused
before the library decodes it. Used by :mod:`.exr`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import BinaryIO

import numba
import numpy as np

MAX_PIXELS = 2**26
"""Largest image (pixels) decoded: 67 megapixels, beyond any camera a rig uses. The size is
checked in the header before anything is decoded, so a small file cannot claim gigabytes."""
_MAX_HEADER_BYTES = 16 * 2**20
"""Headers longer than this (huge preview attributes) skip the chunk-table check."""
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
"""Scanlines per chunk of each OpenEXR compression (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44,
B44A, DWAA, DWAB); files of other compressions skip the chunk-table check."""
_TILED, _DEEP, _MULTIPART = 0x200, 0x800, 0x1000


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


HEAD_BYTES = 2**16
"""Bytes of a file read at once for its header (and, in a small file, everything else)."""


@dataclass(frozen=True)
class ChunkLayout:
    """Where a single-part file's chunk table is: it starts at byte ``table_start`` and has
    ``entries`` offsets, of which the first ``first`` hold the full-resolution level."""

    table_start: int
    entries: int
    first: int
    tiled: bool


def chunk_layout(handle: BinaryIO, head: bytes, size: int) -> tuple[ChunkLayout | str | None, bytes]:
    """The :class:`ChunkLayout` of the open file ``handle`` of ``size`` bytes, whose first bytes
    ``head`` have been read (:data:`HEAD_BYTES` of them, or all); a string saying why its header
    is malformed; or None when it is not checked here (multi-part or deep, an unknown
    compression, a header over the limit). Returned with the bytes read from the start: a header
    longer than ``head`` is read on, up to the limit."""
    version = int.from_bytes(head[4:8], "little")
    if version & (_DEEP | _MULTIPART):
        return None, head
    try:
        parsed = _attributes(head, size)
        if parsed is None:  # a long header: read on, up to the limit
            head += handle.read(_MAX_HEADER_BYTES - len(head))
            parsed = _attributes(head, size)
        if parsed is None:
            return None, head
        attributes, table_start = parsed
        chunks = _chunk_count(attributes, bool(version & _TILED))
    except ValueError as problem:
        return str(problem), head
    if chunks is None:
        return None, head
    return ChunkLayout(table_start, chunks[0], chunks[1], bool(version & _TILED)), head


def chunk_table_problem(handle: BinaryIO, size: int) -> str | None:
    """Why the chunk (offset) table of a single-part file does not fit the file, or None.

    Every offset of the full-resolution level (the one ringlight reads; writers may leave the
    other levels of a mip-map unwritten) must point past the table and inside the file, and the
    chunk at the largest of them must end within the file: a truncated file fails this, as does a
    zeroed table.
    Multi-part and deep files, unknown compressions and headers over the limit are not checked
    here (the library checks them as it decodes). ``handle`` is the open file (at its start),
    ``size`` its length in bytes.
    """
    layout, head = chunk_layout(handle, handle.read(HEAD_BYTES), size)
    if layout is None or isinstance(layout, str):
        return layout
    return offsets_problem(handle, head, size, layout)


def offsets_problem(handle: BinaryIO, head: bytes, size: int, layout: ChunkLayout) -> str | None:
    """Why the chunk table of ``layout`` does not fit a file of ``size`` bytes (see
    :func:`chunk_table_problem`), or None. ``head`` holds the file's first bytes: what lies in it
    is not read again (a small frame is read in one call)."""
    table_end = layout.table_start + 8 * layout.entries
    if table_end > size:
        return f"the file ends at byte {size}, inside its table of {layout.entries} chunk offsets"
    stop = layout.table_start + 8 * layout.first
    if stop <= len(head):
        table = head[layout.table_start:stop]
    else:
        handle.seek(layout.table_start)
        table = handle.read(8 * layout.first)
    if len(table) != 8 * layout.first:
        return "the file changed while it was read"
    # A small frame's few offsets in Python: numpy's reductions cost more than its whole check.
    if layout.first <= 64:
        offsets = struct.unpack(f"<{layout.first}Q", table)
        lowest, last = min(offsets), max(offsets)
    else:
        offsets = np.frombuffer(table, "<u8")
        lowest, last = int(offsets.min()), int(offsets.max())
    if lowest < table_end or last >= size:
        return "a chunk offset points outside the file's data"
    prefix = 20 if layout.tiled else 8  # tile: x, y, level x, level y; scanline: y
    if last + prefix <= len(head):
        chunk_head = head[last:last + prefix]
    else:
        handle.seek(last)
        chunk_head = handle.read(prefix)
    if len(chunk_head) < prefix:
        return f"the file ends at byte {size}, inside its last chunk"
    data_size = int.from_bytes(chunk_head[prefix - 4:], "little", signed=True)
    if data_size < 0 or last + prefix + data_size > size:
        return f"the file ends at byte {size}, before the end of its last chunk"
    return None


@numba.njit(cache=True, nogil=True)
def int_at(data, at, count):  # pragma: no cover - compiled
    """The little-endian integer of ``count`` bytes (4 or 8) at ``data[at]``, signed."""
    value = np.int64(0)
    for i in range(count):
        value |= np.int64(data[at + i]) << np.int64(8 * i)
    if count == 4 and value >= 2**31:
        value -= 2**32
    return value


@numba.njit(cache=True, nogil=True)
def chunks_fit(data, start, size, table_start, chunks):  # pragma: no cover - compiled
    """Whether the scanline chunk table of the file ``data[start:start + size]`` (``chunks`` offsets
    from byte ``table_start``) fits the file, as :func:`.exr_chunks.offsets_problem` checks it:
    every offset past the table and inside the file, the last chunk ending within it. An offset of
    2^63 or more reads negative, and fails."""
    table_end = table_start + 8 * chunks
    if table_end > size or chunks < 1:
        return False
    lowest, last = size, np.int64(-1)
    for index in range(chunks):
        offset = int_at(data, start + table_start + 8 * index, 8)
        lowest = min(lowest, offset)
        last = max(last, offset)
    if lowest < table_end or last >= size or last + 8 > size:
        return False
    length = int_at(data, start + last + 4, 4)
    return length >= 0 and last + 8 + length <= size


@numba.njit(cache=True, nogil=True)
def chunk_tables_fit(data, starts, sizes, table_start, chunks, fits):  # pragma: no cover - compiled
    """``fits[b]``: whether file ``b`` of a run (bytes ``data[starts[b]:starts[b] + sizes[b]]``;
    size -1: not read, False) has a scanline chunk table of ``chunks`` offsets from byte
    ``table_start`` that fits it (:func:`chunks_fit`)."""
    for b in range(sizes.size):
        fits[b] = sizes[b] >= 0 and chunks_fit(data, starts[b], sizes[b], table_start, chunks)
