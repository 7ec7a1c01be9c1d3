"""The table of a store entry's files, and reading them only as it says.

``meta.json`` (:data:`META`) of an entry holds its table: every other file's relative POSIX path,
size and check. A responses chunk's check is its last 4 bytes (the CRC-32C zarr wrote over it),
any other file's (metadata, the small arrays, the manifest's copy) the SHA-256 of its bytes. An
open checks the folder against it (:func:`entry_table`: exactly the table's files at their sizes,
no file read); every read then goes through :class:`TableStore`: the size before the file is read
(a chunk swapped for a huge file is never read), the check after, so that a chunk moved or copied
to another chunk's place fails although its own checksum holds; a file the table names but the
folder lacks is an error, never zarr's fill value (a lost chunk would read as zeros).
"""

from __future__ import annotations

import asyncio
import hashlib
import os
import stat
import threading
from collections.abc import Iterator
from pathlib import Path

import zarr
from zarr.codecs import BloscCodec, Crc32cCodec

META = "meta.json"
"""The entry's own record: key, layout, shape, tile and the table (not in the table)."""
_METADATA = {"zarr.json", ".zgroup", ".zarray", ".zattrs", ".zmetadata"}
"""Metadata files zarr may look for (v3, and v2's when it probes)."""
CHUNK_PREFIX = "responses/c."
"""Names of the responses' chunk files (``responses/c.ROW.COLUMN.0.0``)."""


def store_codecs() -> list:
    """The compressors of every store array: bit shuffling, Blosc-LZ4 at level 9, then a CRC-32C
    of each compressed chunk (:mod:`.response_store` says why)."""
    return [BloscCodec(cname="lz4", clevel=9, shuffle="bitshuffle"), Crc32cCodec()]


def table_of(folder: Path) -> dict[str, list]:
    """The table of an entry just written in ``folder`` (:mod:`.store_table`): relative POSIX path ->
    [size, check]."""
    table = {}
    for path, relative in entry_files(folder):
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            if relative.startswith(CHUNK_PREFIX):
                handle.seek(max(size - 4, 0))
                check = handle.read().hex()
            else:
                check = hashlib.sha256(handle.read()).hexdigest()
        table[relative] = [size, check]
    return table


def entry_files(folder: Path) -> Iterator[tuple[str, str]]:
    """(path, relative POSIX path) of every entry under ``folder`` but its folders (links to
    folders included, never followed); a folder that cannot be read is skipped. Without pathlib
    (a Path a chunk interns each chunk's name for good: 3.7 MB of Python's table of interned
    strings for 1920 chunks) and without recursion (os.walk's: a planted chain of 1500 folders
    raised RecursionError)."""
    pending = [(os.fspath(folder), "")]
    while pending:
        directory, prefix = pending.pop()
        try:
            with os.scandir(directory) as entries:
                found = [(entry.path, prefix + entry.name, entry.is_dir(follow_symlinks=False)) for entry in entries]
        except OSError:
            continue
        for path, relative, is_folder in found:
            if is_folder:
                pending.append((path, relative + "/"))
            else:
                yield path, relative


def file_check(relative: str, data: bytes) -> str:
    """The table's check of a file's bytes (:mod:`.store_table`)."""
    return data[-4:].hex() if relative.startswith(CHUNK_PREFIX) else hashlib.sha256(data).hexdigest()


class DamagedEntry(ValueError):
    """A file of an entry that is not as its table says."""


def read_checked(folder: Path, relative: str, table: dict) -> bytes:
    """The bytes of the entry file ``relative`` when they are as ``table`` says (its size checked
    before they are read); else raises DamagedEntry naming it (a file the table lacks, or absent,
    included). Links are not followed and a FIFO is never waited on."""
    expected = table.get(relative)
    if expected is None:
        raise DamagedEntry(f"{relative} is not one of the entry's files")
    size, check = expected
    try:
        descriptor = os.open(os.path.join(folder, relative), os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as error:
        raise DamagedEntry(f"{relative} cannot be read ({error.strerror or error})") from None
    with os.fdopen(descriptor, "rb") as handle:
        info = os.fstat(handle.fileno())
        if not stat.S_ISREG(info.st_mode) or info.st_size != size:
            raise DamagedEntry(f"{relative} is not the file written there")
        data = handle.read(size + 1)
    if len(data) != size or file_check(relative, data) != check:
        raise DamagedEntry(f"{relative} differs from the file written there")
    return data


class TableStore(zarr.storage.LocalStore):
    """An entry's folder read only, every file as the entry's table says it is (:func:`read_checked`);
    a file the table does not name is absent."""

    def __init__(self, root: Path, table: dict):
        super().__init__(root, read_only=True)
        self._table = table

    async def get(self, key, prototype=None, byte_range=None):
        if key not in self._table:
            return self._absent(key)
        return await asyncio.to_thread(self.get_sync, key, prototype=prototype, byte_range=byte_range)

    def get_sync(self, key, *, prototype=None, byte_range=None):
        """The one way a file is read, whichever path zarr takes (its synchronous one too)."""
        if key not in self._table:
            return self._absent(key)
        if byte_range is not None:  # only sharded arrays ask for parts of a file
            raise DamagedEntry(f"{key}: a part of a file was asked for; the entry's arrays are not sharded")
        data = read_checked(self.root, key, self._table)
        return (prototype or zarr.core.buffer.default_buffer_prototype()).buffer.from_bytes(data)

    @staticmethod
    def _absent(key: str) -> None:
        """A file the table does not name: metadata zarr looks for is absent (None); a chunk is an
        error, never zarr's fill value (metadata edited to other chunk names, its table with it)."""
        if key.rsplit("/", 1)[-1] in _METADATA:
            return None
        raise DamagedEntry(f"{key} is not one of the entry's files")

    async def get_partial_values(self, prototype, key_ranges):
        raise DamagedEntry("parts of files were asked for; the entry's arrays are not sharded")

    async def exists(self, key: str) -> bool:
        return key in self._table


def chunks_listed(table: dict, shape: tuple[int, ...], tile: int) -> bool:
    """Whether the table lists every chunk of the arrays of ``shape`` (float32 responses) in tiles
    of ``tile``, none larger than :func:`most_bytes` of its raw size: a chunk it lacks would read
    as zarr's fill value."""
    rows, columns = -(-shape[0] // tile), -(-shape[1] // tile)
    chunks = sum(1 for name in table if name.startswith(CHUNK_PREFIX))
    raw = tile * tile * shape[2] * shape[3] * 4
    return (chunks == rows * columns and all(f"{CHUNK_PREFIX}{row}.{column}.0.0" in table
                                             for row in range(rows) for column in range(columns))
            and all(size <= most_bytes(raw) for name, (size, _) in table.items() if name.startswith(CHUNK_PREFIX))
            and all(name in table for name in ("lit_counts/c.0.0", "observed/c.0.0", "steady/c.0.0.0")))


def most_bytes(raw: int) -> int:
    """The most bytes a chunk of ``raw`` bytes takes once compressed and checksummed (Blosc's
    headers and its blocks stored raw when they do not compress): a file the table says is
    larger is never read (a 4 GiB sparse file whose size was edited into the table)."""
    return raw + raw // 16 + 1024


def entry_table(location: Path, meta: dict) -> dict | None:
    """The table of the entry at ``location`` from its ``meta``, when it is well formed and the
    folder holds exactly its files at their sizes, and nothing but regular files and folders;
    else None. Reads no file."""
    table = meta.get("table")
    if not isinstance(table, dict) or not all(
            isinstance(entry, list) and len(entry) == 2 and type(entry[0]) is int and isinstance(entry[1], str)
            for entry in table.values()):
        return None
    found = 0
    for path, relative in entry_files(location):
        if relative == META:
            continue
        info = os.lstat(path)
        if not stat.S_ISREG(info.st_mode) or table.get(relative, [None])[0] != info.st_size:
            return None
        found += 1
    return table if found == len(table) else None


def settle_reads() -> None:
    """Wait until zarr's event loop has finished every read it still holds. A read that fails in
    one chunk raises while the loop still reads its others; a command that then reports the error
    and exits left them pending, and Python printed a warning and a traceback for each (after the
    error's one line). One thread settles at a time, and a settle never waits on another's: two
    that gathered each other's task waited for good (two workers missing a cache at once)."""
    async def settle() -> None:
        asyncio.current_task().set_name(_SETTLING)
        others = [task for task in asyncio.all_tasks() if task.get_name() != _SETTLING]
        await asyncio.gather(*others, return_exceptions=True)

    with _SETTLE_LOCK:
        try:
            zarr.core.sync.sync(settle())
        except Exception:  # nothing to add to the error being reported
            pass


_SETTLING = "ringlight: settling zarr's reads"
_SETTLE_LOCK = threading.Lock()
