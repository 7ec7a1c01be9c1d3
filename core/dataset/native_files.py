"""The system calls that visit a dataset's small files, made from compiled code.

Made from Python, each of a small frame's calls (open, fstat, read, close) costs about as much
interpreter around it as the kernel's own work, and that was most of an open of a long
manifest. Here one compiled call visits a run of files: each is opened relative to the dataset
folder's descriptor (``openat``: its folders are not walked again from the root), its type, size
and identity taken from the open file (``statx``), read whole into one buffer and closed,
through libc's functions as :mod:`.exr_small` calls zlib's. :func:`stat_files` gives a reopen's
key the identity of each file (``statx`` by name, following links as ``os.stat`` does).

Only the usual case is taken here: a file that cannot be opened or stat'ed, or is not a regular
file, is handed back (marked) for Python's calls to visit it as before, which say what is wrong in
the same words. :data:`NATIVE_FILES` is False where ``statx`` is missing (not Linux, a C library
before glibc 2.28) or does not give what ``os.stat`` gives; the files are then visited from Python.
"""

from __future__ import annotations

import ctypes
import os
import stat
import sys

import numba
import numpy as np

from .exr_chunks import int_at

STATX_BYTES = 256
"""Size of Linux's ``struct statx``, whose layout is the same on every architecture."""
_AT_FDCWD, _AT_EMPTY_PATH = -100, 0x1000
_MASK = 0x1 | 0x2 | 0x40 | 0x80 | 0x100 | 0x200
"""STATX_TYPE | STATX_MODE | STATX_MTIME | STATX_CTIME | STATX_INO | STATX_SIZE: what is asked, and
must be answered (a file system that cannot give one is visited from Python)."""
_MODE, _INO, _SIZE, _CTIME, _MTIME = 28, 32, 40, 96, 112
"""Byte offsets in ``struct statx`` of stx_mode (u16), stx_ino, stx_size (u64) and the change and
modification times (i64 seconds, then u32 nanoseconds)."""

# openat is variadic in C (a mode follows for O_CREAT): declared here with the mode as a fourth
# fixed argument, which the x86-64 and AArch64 Linux calling conventions pass as they pass a
# variadic one.
_openat = numba.types.ExternalFunction("openat", numba.types.intc(numba.types.intc, numba.types.voidptr,
                                                                 numba.types.intc, numba.types.intc))
_statx = numba.types.ExternalFunction("statx", numba.types.intc(numba.types.intc, numba.types.voidptr,
                                                               numba.types.intc, numba.types.uintc,
                                                               numba.types.voidptr))
_read = numba.types.ExternalFunction("read", numba.types.intp(numba.types.intc, numba.types.voidptr,
                                                             numba.types.uintp))
_close = numba.types.ExternalFunction("close", numba.types.intc(numba.types.intc))
_memcmp = numba.types.ExternalFunction("memcmp", numba.types.intc(numba.types.voidptr, numba.types.voidptr,
                                                                 numba.types.uintp))


def _identity_of(status: bytes) -> tuple[int, int, int, int]:
    """:func:`.cache.file_identity` from the bytes of a ``struct statx`` (little-endian)."""
    def number(at: int, count: int, signed: bool = False) -> int:
        return int.from_bytes(status[at:at + count], "little", signed=signed)

    return (number(_SIZE, 8), number(_MTIME, 8, True) * 10**9 + number(_MTIME + 8, 4), number(_INO, 8),
            number(_CTIME, 8, True) * 10**9 + number(_CTIME + 8, 4))


def _native_files() -> bool:
    """Whether libc has the calls and ``statx`` of this module's file gives ``os.stat``'s identity
    (a check of the layout above; ENOSYS where a sandbox forbids the call)."""
    if not sys.platform.startswith("linux") or sys.byteorder != "little":
        return False
    try:
        libc = ctypes.CDLL(None)
        for name in ("openat", "read", "close", "memcmp"):
            getattr(libc, name)
        call = libc.statx
    except (OSError, AttributeError):
        return False
    call.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_uint, ctypes.c_void_p]
    status = ctypes.create_string_buffer(STATX_BYTES)
    path = os.fsencode(__file__)
    if call(_AT_FDCWD, path, 0, _MASK, status) != 0 or int.from_bytes(status[0:4], "little") & _MASK != _MASK:
        return False
    info = os.stat(path)
    return _identity_of(status.raw) == (info.st_size, info.st_mtime_ns, info.st_ino, info.st_ctime_ns) \
        and stat.S_IFMT(int.from_bytes(status[_MODE:_MODE + 2], "little")) == stat.S_IFREG


NATIVE_FILES = _native_files()
"""Whether :func:`read_files` and :func:`stat_files` can be called (see the module docstring)."""


def encoded_names(names) -> tuple[np.ndarray, np.ndarray] | None:
    """The file names ``names`` (str) as the bytes the system is given (``os.fsencode``), each
    ended by a NUL, in one (bytes,) uint8 array, and (len(names),) int64 where each starts; None
    when one cannot be encoded or holds a NUL (Python's calls then say what is wrong)."""
    try:
        data = np.frombuffer(os.fsencode("\0".join(names) + "\0"), np.uint8)
    except (UnicodeError, ValueError):
        return None
    ends = np.flatnonzero(data == 0)
    if len(ends) != len(names):
        return None
    starts = np.zeros(len(names), np.int64)
    starts[1:] = ends[:-1] + 1
    return data, starts


def open_folder(folder) -> int | None:
    """A descriptor of the dataset folder that names are relative to, or None where it cannot be
    opened (its files are then visited from Python, which says why)."""
    try:
        return os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        return None


def new_scratch() -> np.ndarray:
    """The scratch :func:`read_files` and :func:`stat_files` take: a ``struct statx``, then a NUL
    (the empty name that makes ``statx`` stat an open file)."""
    return np.zeros(STATX_BYTES + 1, np.uint8)


@numba.njit(cache=True, nogil=True)
def _identity(status, identity):  # pragma: no cover - compiled
    """``identity`` (4,) int64 := size, mtime (ns), inode, ctime (ns) of a ``struct statx``;
    False unless it answered all that :data:`_MASK` asks and is a regular file."""
    if int_at(status, 0, 4) & _MASK != _MASK:
        return False
    identity[0] = int_at(status, _SIZE, 8)
    identity[1] = int_at(status, _MTIME, 8) * 1_000_000_000 + int_at(status, _MTIME + 8, 4)
    identity[2] = int_at(status, _INO, 8)
    identity[3] = int_at(status, _CTIME, 8) * 1_000_000_000 + int_at(status, _CTIME + 8, 4)
    mode = np.int64(status[_MODE]) | (np.int64(status[_MODE + 1]) << 8)
    return mode & 0o170000 == 0o100000


HANDED_BACK = -2
"""Size :func:`read_files` gives a file it does not take, for Python's calls to visit."""


@numba.njit(cache=True, nogil=True)
def read_files(folder, names, name_starts, inside, flags, limit, header, data, used, starts, sizes, identities,
               scratch):  # pragma: no cover - compiled
    """Visit the files of a run (see the module docstring).

    Parameters
    ----------
    folder
        Descriptor of the dataset folder the names are relative to.
    names, name_starts
        The names (:func:`encoded_names`).
    inside
        (n,) bool: whether each file's folder is known to be inside the dataset folder (or need
        not be); a file whose is not is handed back.
    flags
        ``openat``'s flags (read only, never waiting on a FIFO, not following a last link unless
        files may lie outside).
    limit
        Most bytes of a file read whole (:data:`.exr_chunks.HEAD_BYTES`).
    header
        (h,) uint8: the bytes a file read whole starts with (the header the run shares).
    data, used
        The buffer and how many of its bytes hold files; it is grown (a new array) when full.
    starts, sizes, identities
        (n,), (n,) int64 and (n, 4) int64 (-1 on the way in), written for each file: where its
        bytes start in ``data`` and how many there are (-1: larger than ``limit``, not of
        ``header``, or not read whole, for the caller to read alone; :data:`HANDED_BACK`: a file
        this does not take, a link, one that cannot be opened or stat'ed or is not a regular
        file), and its identity (:func:`.cache.file_identity`).
    scratch
        :func:`new_scratch`.

    Returns
    -------
    ``(data, used)``: the buffer and its bytes used.
    """
    status = scratch[:STATX_BYTES]
    empty = scratch[STATX_BYTES:]
    for i in range(sizes.size):
        sizes[i] = HANDED_BACK
        name = names[name_starts[i]:]
        if not inside[i] or name[0] == 47:  # '/': no name of a dataset, but not relative to folder
            continue
        descriptor = _openat(folder, name.ctypes.data, flags, 0)
        if descriptor < 0:
            continue
        if _statx(descriptor, empty.ctypes.data, _AT_EMPTY_PATH, _MASK, status.ctypes.data) != 0 \
                or not _identity(status, identities[i]):
            identities[i] = -1
            _close(descriptor)
            continue
        size = identities[i, 0]
        starts[i] = used
        sizes[i] = -1
        if size <= limit:
            if used + size + 1 > data.size:
                grown = np.empty(max(2 * data.size, used + size + 1), np.uint8)
                grown[:used] = data[:used]
                data = grown
            # One byte more than its size: a file that grew since is not taken as whole.
            got = _read(descriptor, data[used:].ctypes.data, size + 1)
            # memcmp: a comparison of slices made an array a file, a loop took a step a byte.
            if got == size and size >= header.size \
                    and _memcmp(data[used:].ctypes.data, header.ctypes.data, header.size) == 0:
                sizes[i] = size
                used += size
        _close(descriptor)
    return data, used


@numba.njit(cache=True, nogil=True)
def stat_files(folder, names, name_starts, identities, missed, scratch):  # pragma: no cover - compiled
    """``identities[i]`` (:func:`.cache.file_identity`) of each file (names relative to the
    descriptor ``folder``, :func:`encoded_names`), links followed; ``missed[i]`` True for one that
    ``statx`` cannot answer in full, for ``os.stat`` to say."""
    status = scratch[:STATX_BYTES]
    for i in range(identities.shape[0]):
        name = names[name_starts[i]:]
        missed[i] = name[0] == 47 or _statx(folder, name.ctypes.data, 0, _MASK, status.ctypes.data) != 0 \
            or int_at(status, 0, 4) & _MASK != _MASK
        if not missed[i]:
            _identity(status, identities[i])


@numba.njit(cache=True, nogil=True)
def folder_changes(names, name_starts):  # pragma: no cover - compiled
    """Indices of the names whose folder (all before the last '/') is not the previous name's:
    0, then one a change (a manifest's frames mostly share one folder)."""
    count = name_starts.size
    changes = np.empty(count, np.int64)
    found = 0
    previous_start, previous_length = np.int64(0), np.int64(-1)
    for i in range(count):
        start = name_starts[i]
        end = start
        length = np.int64(0)
        while names[end] != 0:
            if names[end] == 47:
                length = end - start
            end += 1
        same = length == previous_length
        if same:
            for k in range(length):
                if names[start + k] != names[previous_start + k]:
                    same = False
                    break
        if not same:
            changes[found] = i
            found += 1
        previous_start, previous_length = start, length
    return changes[:found]
