"""The chunked, compressed, checksummed store of a dataset's responses (zarr v3).

An entry is a folder (where :func:`.cache.cache_location` says) holding a zarr v3 group and
ringlight's ``meta.json``:

- ``responses``: (H, W, K, 3) float32 in chunks of ``tile x tile`` grid points with every offset
  and channel inside (a point's responses are one chunk's; a band of ``tile`` rows is one row of
  chunks). Inside a chunk the values are stored offset-major, (K, 3, tile, tile): one offset's
  responses over neighbouring points form a smooth image (light from the same distance and
  direction), which compresses 2.5x better than one point's profile after another (measured on
  ``benchmarks/bench_scale.py``'s data: 42 against 105 MiB at 128 px). Then Blosc-LZ4 at level 9
  with bit shuffling (float32 values from half-float frames leave 13 zero bits that it packs away),
  then a CRC-32C of each compressed chunk. Byte shuffling packs the smooth benchmark data better,
  but bit shuffling is smaller on data with 5 % noise, which real captures have. Measured on the
  benchmark's 256 px responses (1.31 GiB) and on the same with 5 % noise, store GiB and write /
  read CPU seconds: Blosc-zstd level 1, bit shuffle 0.171 / 3.2-3.4 / 2.7-3.0 (noisy 0.402 GiB);
  LZ4 level 9, bit shuffle 0.168 / 2.0-2.1 / 2.2-2.5 (noisy 0.424 GiB); LZ4 level 1 0.310 (byte
  shuffle 0.216, noisy 0.628);
- ``lit_counts`` (H, W) int32, ``observed`` (H, W) bool, ``steady`` (H, W, 3) float32 (the steady
  state, so that an open shows it without reading the responses), same codecs;
- ``manifest.npz``: the manifest the entry was built from (:mod:`.manifest_copy`), so that a
  reopen need not parse its JSON;
- ``meta.json``: the cache key (:func:`.cache.files_key`) and its manifest part
  (:func:`.cache.manifest_key`, which tells an open whether the files need be stat'ed at all), the
  frames' channels (which a reopen then need not read from the first frame's header), the layout
  version, the shape, the tile and the entry's table of files (:mod:`.store_table`).

Opening validates lazily. Up front, without reading a chunk: the key, the arrays' shapes and
types, and the folder against the table (exactly its files, at their sizes; a symbolic link, FIFO
or device planted in it is never opened). Every file is then read only as the table says it is,
and zarr checks the checksum of what it decodes. A file that fails raises
:class:`~ringlight.core.errors.DatasetError` naming the store, and the entry is marked stale so
that the next open rebuilds it. Entries are written in a temporary folder and renamed into place
(:func:`ringlight.core.atomic.atomic_folder`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
import threading
from collections import OrderedDict, deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import TransposeCodec

from ..atomic import atomic_folder
from ..errors import DatasetError, RinglightError
from ..validation import read_json
from .store_table import (
    META,
    TableStore,
    chunks_listed,
    entry_files,
    entry_table,
    read_checked,
    settle_reads,
    store_codecs,
    table_of,
)

LAYOUT_VERSION = 6
"""3: chunks offset-major; 4: the entry also holds the manifest's copy (:mod:`.manifest_copy`);
5: meta.json holds the entry's table of files; 6: and the key's manifest part."""
CHUNK_BYTES = 8 * 2**20
"""Target size of one uncompressed responses chunk: big enough for compression and few files,
small enough that a click (one point's chunk) decodes in a few milliseconds."""
MAX_META_BYTES = 2**24
"""Largest meta.json read: its table takes about 45 bytes a chunk (4096 chunks at 1024 px)."""
_SMALL = ("lit_counts", "observed", "steady")
OFFSET_MAJOR = (2, 3, 0, 1)
"""Order of the responses' axes inside a stored chunk (module docstring)."""
_FLAT_KEYS = {"name": "default", "separator": "."}
"""Chunk files named ``c.ROW.COLUMN.0.0`` in their array's folder, not nested folders: a reopen's
walk of the names then lists a few folders, not one per chunk."""


def store_tile(grid_shape: tuple[int, int], offsets: int) -> int:
    """Side (grid points) of a responses chunk: about :data:`CHUNK_BYTES` of (K, 3) float32 each,
    as a multiple of 16 rows once that is 8 or more (a 14-point side rounds up to 16). Bands then
    start on the 16-line chunks of ZIP- and PIZ-compressed EXR, so that a band decodes none of its
    neighbours' lines, and each offset's image in a chunk is a whole number of bit-shuffle
    blocks: at 1024 px, R 32 a 14-point side compressed to 0.215 of raw float32, 16 to 0.134."""
    side = int(math.sqrt(CHUNK_BYTES / max(offsets * 12, 1)))
    if side >= 8:
        side = max(16, int(round(side / 16)) * 16)
    return max(1, min(side, max(grid_shape)))


class StoreWriter:
    """Writes an entry's arrays; made by :func:`write_store`. Bands of responses are written in
    row order, each a whole number of tiles high (the last one may be shorter)."""

    def __init__(self, folder: Path, shape: tuple[int, ...], tile: int):
        self.folder, self.shape, self.tile = folder, shape, tile
        self.key: str | None = None
        """The entry's key (:func:`.cache.files_key`), set once the frames are read: it holds the
        identity of each frame file as it was read."""
        group = zarr.open_group(zarr.storage.LocalStore(folder), mode="w")
        self._group = group
        self._responses = group.create_array(
            "responses", shape=shape, chunks=(tile, tile, shape[2], shape[3]), dtype="float32", fill_value=0.0,
            filters=[TransposeCodec(order=OFFSET_MAJOR)], compressors=store_codecs(), config={"write_empty_chunks": True},
            chunk_key_encoding=_FLAT_KEYS)

    def write_rows(self, row0: int, band: np.ndarray) -> None:
        """Store responses rows ``row0 .. row0 + len(band)`` ((rows, W, K, 3) float32)."""
        if row0 % self.tile:
            raise ValueError(f"band starts at row {row0}, not on a tile boundary ({self.tile})")
        tile = self.tile

        def write(corner: tuple[int, int]) -> None:
            y, x = corner
            self._responses[row0 + y:row0 + y + tile, x:x + tile] = band[y:y + tile, x:x + tile]

        # A chunk at a time, from a thread a core: zarr compresses the chunks of one call side by
        # side, but a call of several chunks first copies each into a new chunk array in its event
        # loop's thread, one after the other, where a call of exactly one chunk encodes the band's
        # view as it is.
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        with ThreadPoolExecutor(max_workers=workers) as pool:
            pending: deque = deque()
            for y in range(0, band.shape[0], tile):
                for x in range(0, band.shape[1], tile):
                    if len(pending) == 2 * workers:  # a few chunks in flight, not a future per chunk
                        pending.popleft().result()
                    pending.append(pool.submit(write, (y, x)))
            for future in pending:
                future.result()

    def write_small(self, lit_counts: np.ndarray, observed: np.ndarray, steady: np.ndarray) -> None:
        for name, array in zip(_SMALL, (lit_counts, observed, steady)):
            stored = self._group.create_array(name, shape=array.shape, chunks=array.shape, dtype=array.dtype,
                                              compressors=store_codecs(), config={"write_empty_chunks": True},
                                              chunk_key_encoding=_FLAT_KEYS)
            stored[...] = array


@contextmanager
def write_store(location: Path, manifest_key: str, shape: tuple[int, ...], tile: int,
                channels: tuple[str, ...]) -> Iterator[StoreWriter]:
    """Write an entry at ``location`` atomically: the caller fills the yielded writer and sets its
    :attr:`~StoreWriter.key` (the entry is of the manifest of key ``manifest_key``, its frames
    read with ``channels``: :func:`.frames.dataset_channels`); on leaving
    without an error the entry is published, on an error (or :class:`Cancelled`) nothing is left.

    Raises the caller's errors, and OSError or RinglightError when the folder cannot be written
    (``location`` exists as anything but a real folder: replacing it would follow a link).
    """
    try:
        if not stat.S_ISDIR(os.lstat(location).st_mode):
            raise OSError(f"{location} is not a folder")
    except FileNotFoundError:
        pass
    with atomic_folder(location) as staging:
        writer = StoreWriter(staging, shape, tile)
        yield writer
        if writer.key is None:
            raise ValueError("a store entry written without its key")
        meta = {"key": _entry_key(writer.key, list(channels)), "manifest_key": manifest_key, "channels": list(channels),
                "layout": LAYOUT_VERSION, "shape": list(shape), "tile": tile, "table": table_of(staging)}
        (staging / META).write_text(json.dumps(meta), encoding="utf-8")


def entry_file(location: Path, relative: str) -> bytes | None:
    """The bytes of one file of the entry at ``location`` (of this layout) as its table says they
    are, or None (no entry, a damaged one, or a file other than written)."""
    try:
        meta = _meta(location)
        if meta is None or not isinstance(meta.get("table"), dict):
            return None
        return read_checked(location, relative, meta["table"])
    except (OSError, ValueError, TypeError, RinglightError):
        return None


def stored_manifest_key(location: Path) -> str | None:
    """The manifest key (:func:`.cache.manifest_key`) of the entry at ``location``, or None (no
    entry, a damaged one, one of another layout); stats no dataset file."""
    try:
        meta = _meta(location)
    except (OSError, RinglightError):
        return None
    key = None if meta is None else meta.get("manifest_key")
    return key if isinstance(key, str) else None


def _meta(location: Path) -> dict | None:
    """The entry's meta.json when it is a regular file of this layout, else None (raises OSError
    or RinglightError for a file that cannot be read)."""
    if not stat.S_ISREG(os.lstat(location / META).st_mode):
        return None
    meta = read_json(location / META, _StoreInvalid, "cache meta.json", max_bytes=MAX_META_BYTES)
    return meta if isinstance(meta, dict) and meta.get("layout") == LAYOUT_VERSION else None


class ResponseStore:
    """An entry opened for reading: the responses read band by band (decoded bands kept up to a
    byte budget, least recently used dropped first), the small arrays in memory.

    Attributes
    ----------
    path
        The entry's folder.
    tile
        Side of a responses chunk (grid points): bands are read ``tile`` rows at a time.
    lit_counts, observed, steady
        The small arrays (see the module docstring).
    channels
        The channels the frames were read with (see :func:`write_store`).
    """

    def __init__(self, path: Path, responses: zarr.Array, tile: int, lit_counts: np.ndarray,
                 observed: np.ndarray, steady: np.ndarray, keep_bytes: int, meta_identity: tuple,
                 channels: tuple[str, ...]):
        self.path, self.tile, self.channels = path, tile, channels
        self._meta_identity = meta_identity  # of the meta.json it was opened by: see mark_stale
        self._responses = responses
        self.lit_counts, self.observed, self.steady = lit_counts, observed, steady
        self._keep_bytes = keep_bytes
        self._bands: OrderedDict[int, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self._responses.shape)

    def band(self, index: int) -> np.ndarray:
        """Rows ``index * tile`` onward (``tile`` of them, fewer at the end): (rows, W, K, 3)
        float32, read-only."""
        with self._lock:
            if index in self._bands:
                self._bands.move_to_end(index)
                return self._bands[index]
        row0 = index * self.tile
        try:
            band = self._responses[row0:min(row0 + self.tile, self.shape[0])]
        except (ValueError, OSError, RuntimeError) as error:  # a checksum or a decode that failed
            raise self._damaged(f"in rows {row0}.. ", error) from None
        band.flags.writeable = False
        with self._lock:
            self._bands[index] = band
            while len(self._bands) > 1 and sum(b.nbytes for b in self._bands.values()) > self._keep_bytes:
                self._bands.popitem(last=False)
        return band

    def rows(self, row0: int, row1: int) -> np.ndarray:
        """Responses of rows ``row0 .. row1`` (a view when they lie in one band, else a copy)."""
        first, last = row0 // self.tile, (row1 - 1) // self.tile
        if first == last:
            return self.band(first)[row0 - first * self.tile:row1 - first * self.tile]
        return np.concatenate([self.band(index)[max(row0 - index * self.tile, 0):row1 - index * self.tile]
                               for index in range(first, last + 1)])

    def window(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """Responses of a window of grid points, reading only the chunks it touches."""
        try:
            return self._responses[row0:row1, col0:col1]
        except (ValueError, OSError, RuntimeError) as error:
            raise self._damaged("", error) from None

    def _damaged(self, where: str, error: Exception) -> DatasetError:
        """The one-line error of a read that failed, once the entry is marked stale and zarr's
        other reads have ended (:func:`.store_table.settle_reads`)."""
        mark_stale(self.path, self._meta_identity)
        settle_reads()
        return DatasetError(f"{self.path}: damaged cache chunk {where}({error}); open the dataset again to rebuild it")


def open_store(location: Path, key: str, shape: tuple[int, ...], keep_bytes: int) -> ResponseStore | None:
    """The entry at ``location`` for ``key`` and a responses array of ``shape``, or None when it
    is absent, stale or fails a check (module docstring); reads no responses chunk."""
    try:
        if not stat.S_ISDIR(os.lstat(location).st_mode):
            return None
        meta = _current_meta(location, key)
        if meta is None:
            return None
        identity = _identity(location / META)
        if meta.get("shape") != list(shape) or not isinstance(meta.get("tile"), int) or meta["tile"] < 1:
            return None
        channels = meta.get("channels")
        if not isinstance(channels, list) or len(channels) not in (1, 3) or len(set(channels)) != len(channels) \
                or not all(isinstance(name, str) and name for name in channels):
            return None
        table = entry_table(location, meta)
        if table is None or not chunks_listed(table, shape, meta["tile"]):
            return None
        group = zarr.open_group(TableStore(location, table), mode="r", zarr_format=3)
        responses = group["responses"]
        height, width = shape[:2]
        expected = {"lit_counts": ((height, width), np.int32), "observed": ((height, width), np.bool_),
                    "steady": ((height, width, 3), np.float32)}
        if not isinstance(responses, zarr.Array) or responses.shape != tuple(shape) \
                or responses.dtype != np.float32 or responses.chunks != (meta["tile"], meta["tile"], shape[2], shape[3]):
            return None
        small = {}
        for name in _SMALL:
            array = group[name]
            if not isinstance(array, zarr.Array) \
                    or (array.shape, array.dtype) != (expected[name][0], np.dtype(expected[name][1])):
                return None
            small[name] = array[...]
    except (OSError, ValueError, KeyError, TypeError, RuntimeError, RinglightError):
        return None
    return ResponseStore(location, responses, meta["tile"], small["lit_counts"], small["observed"],
                         small["steady"], keep_bytes, identity, tuple(channels))


def stored_entry_bytes(location: Path, key: str) -> int | None:
    """Bytes on disk of the entry at ``location`` when its key is ``key``, else None (no chunk
    is read)."""
    try:
        return None if _current_meta(location, key) is None else entry_bytes(location)
    except (OSError, RinglightError):
        return None


def _current_meta(location: Path, key: str) -> dict | None:
    """The entry's meta.json when it is a regular file of this layout written for ``key``, else
    None (raises OSError or RinglightError for a file that cannot be read)."""
    meta = _meta(location)
    return meta if meta is not None and meta.get("key") == _entry_key(key, meta.get("channels")) else None


def _entry_key(key: str, channels: object) -> str:
    """What meta.json records as the key of an entry of store key ``key`` whose frames were read
    with ``channels``: the two bound, so that edited channels fail the key as an edited key does
    (anything but a list of names matches no key)."""
    if not isinstance(channels, list) or not all(isinstance(name, str) for name in channels):
        return ""
    return hashlib.sha256(f"{key}\0{json.dumps(channels)}".encode()).hexdigest()


def entry_bytes(location: Path) -> int:
    """Bytes the files under ``location`` take (0 when it does not exist, or is a link: an entry
    is never one, and a cache folder linked to ``/`` must not cost a walk of the whole disk)."""
    if os.path.islink(location):
        return 0
    total = 0
    for path, _ in entry_files(location):
        try:
            total += os.lstat(path).st_size
        except OSError:
            pass
    return total


def mark_stale(location: Path, identity: tuple) -> None:
    """Make the entry fail its next open (its meta.json removed), so that it is rebuilt; only
    while its meta.json is still the one of ``identity`` (:func:`_identity`): another open may
    have replaced the entry since this one was opened (the old one's reads then fail), and the
    new entry is not damaged."""
    try:
        if _identity(location / META) == identity:
            os.unlink(location / META)
    except OSError:
        pass


def _identity(path: Path) -> tuple:
    """Which file ``path`` is: device, inode, size and modification time."""
    info = os.lstat(path)
    return info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns


class _StoreInvalid(RinglightError):
    """A store file that cannot be used; the entry is rebuilt, so users never see this."""
