"""User cache files of arrays that carry their own check: the ``.npz`` files ringlight keeps in
the user cache (``simulate --noise`` checkpoints, the inversion's white databases).

A file is an uncompressed ``.npz`` (numpy's own format) holding the arrays, the key of what they
were computed for (another run's file copied under this name is told apart) and a SHA-256
digest of the key and of every array's name, dtype, shape and bytes. Reading trusts nothing
before it is checked: the file must be a regular file (opened without blocking, so a FIFO put in
its place is refused at once, not waited on), each array's header is read first and its declared
size must be what the file holds (a flipped bit in a header asked numpy for 33 GiB), and the
digest must match. Any damage (truncation, a flipped bit, wrong contents, a foreign file) is
:class:`DamagedFile` with one line saying what; callers then recompute or report it.
"""

from __future__ import annotations

import hashlib
import math
import os
import stat
import struct
import zipfile
from pathlib import Path

import numpy as np

from .atomic import atomic_file

_KEY = "key"
_CHECK = "check"
MAX_ARRAYS = 16
"""Most arrays a checked file holds (a file listing more is not one of ringlight's)."""


class DamagedFile(ValueError):
    """A checked file that cannot be trusted; the message says why (without the path)."""


class NotAFile(DamagedFile):
    """Something other than a regular file (a FIFO, a folder, a device) where a checked file
    belongs: not ringlight's to replace."""


def digest(key: str, arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 of ``key`` and each array's name, dtype, shape and bytes, in name order."""
    hashed = hashlib.sha256(key.encode())
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        hashed.update(f"\0{name}\0{array.dtype.str}\0{array.shape}\0".encode())
        hashed.update(array.tobytes())
    return hashed.hexdigest()


def save_checked(path: Path, key: str, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` with ``key`` and their digest to ``path`` atomically (replacing the file)."""
    arrays = {name: np.asarray(value) for name, value in arrays.items()}
    with atomic_file(path, overwrite=True) as temporary:
        with open(temporary, "wb") as handle:
            np.savez(handle, **arrays, **{_KEY: np.array(key), _CHECK: np.array(digest(key, arrays))})


def load_checked(path: Path, key: str, names: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    """The arrays ``names`` saved by :func:`save_checked` at ``path`` for ``key``; None when there
    is no file. Raises :class:`DamagedFile` when the file is there but not exactly what was saved
    for ``key``. Memory is bounded by the file's size: no array larger than its bytes in the file
    is allocated."""
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as error:  # a folder opens; a dangling link or a socket does not
        raise NotAFile(error.strerror or str(error)) from None
    with os.fdopen(descriptor, "rb") as handle:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise NotAFile("not a regular file")
        try:
            arrays = _read_arrays(handle, {*names, _KEY, _CHECK}, os.fstat(descriptor).st_size)
        except (OSError, EOFError, KeyError, struct.error, zipfile.BadZipFile, zipfile.LargeZipFile,
                NotImplementedError, UnicodeDecodeError, ValueError) as error:
            raise DamagedFile(f"damaged ({type(error).__name__}: {str(error)[:120]})") from None
    stored_key, stored_check = arrays.pop(_KEY), arrays.pop(_CHECK)
    if stored_key.dtype.kind != "U" or stored_key.shape != () or str(stored_key) != key:
        raise DamagedFile("it was written for another run")
    if stored_check.dtype.kind != "U" or stored_check.shape != () or str(stored_check) != digest(key, arrays):
        raise DamagedFile("its contents do not match their check (a damaged or edited file)")
    return arrays


def _read_arrays(handle, names: set[str], length: int) -> dict[str, np.ndarray]:
    """Read the ``.npy`` members ``names`` from the open ``.npz`` ``handle`` of ``length`` bytes,
    each stored (uncompressed, as :func:`numpy.savez` writes) within the file."""
    with zipfile.ZipFile(handle) as archive:
        members = archive.infolist()
        if len(members) > MAX_ARRAYS + 2:
            raise ValueError(f"{len(members)} members")
        found = {member.filename.removesuffix(".npy"): member for member in members}
        missing = sorted(names - found.keys())
        if missing:
            raise DamagedFile(f"it has no {' and no '.join(missing)} "
                              "(written by an older ringlight, another program or by hand)")
        for name in names:
            member = found[name]
            if (member.compress_type != zipfile.ZIP_STORED or member.file_size != member.compress_size
                    or member.header_offset + member.compress_size > length):
                raise ValueError(f"{name} is not stored within the file")
        return {name: _read_member(archive, found[name]) for name in sorted(names)}


def _read_member(archive: zipfile.ZipFile, member: zipfile.ZipInfo) -> np.ndarray:
    with archive.open(member) as stream:
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(stream)
        else:
            raise ValueError(f"npy version {version}")
        if dtype.hasobject or fortran:
            raise ValueError("not a plain array")
        size = math.prod(shape) * dtype.itemsize  # Python integers: a huge shape cannot wrap
        if size != member.file_size - stream.tell():
            raise ValueError(f"declares {size} bytes, holds {member.file_size - stream.tell()}")
        array = np.empty(shape, dtype)
        if size and stream.readinto(memoryview(array.reshape(-1).view(np.uint8))) != size:
            raise EOFError("truncated")
        return array
