"""Reading a run of a dataset's small files whole, in one buffer, for one compiled pass over them.

A long manifest's frames are small files that share one header (one camera, one writer): what
each costs is its system calls. :func:`read_run` visits each file of a run once: it is opened
inside the dataset folder, stat'ed (its size, and its identity for the store's key), read whole
in one ``read`` when it has at most :data:`.exr_chunks.HEAD_BYTES` and starts with the header
bytes the run shares, and closed. Where it can, one compiled call makes these calls for a whole
run (:mod:`.native_files`: 100 000 frames took 13 us of CPU each from Python, 5 us so); a file it
does not take (a link, one that cannot be opened, not a regular file) is visited from Python
(:meth:`.file_paths.FileResolver.open`: located, checked inside the dataset folder and opened in
one call). The bytes of all the files go into one array, each file's at its offset, which a
compiled pass then checks (:mod:`.checks`) or decodes (:mod:`.frame_batch`) in one call. A file
that does not start with the shared header, or is larger, is marked for its caller to read alone,
as before (its problem, if it has one, is then said as it always was); the error of a file that
cannot be opened is kept for the caller to raise or report in its place, so that problems keep the
manifest's order.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import DatasetError
from .cache import IDENTITY_FIELDS, file_identity
from .exr_chunks import HEAD_BYTES
from .file_paths import FileResolver
from .native_files import (HANDED_BACK, NATIVE_FILES, encoded_names, folder_changes, new_scratch, open_folder,
                           read_files)


@dataclass(frozen=True, eq=False)
class FileRun:
    """The files of a run read (see the module docstring), ``n`` of them.

    Attributes
    ----------
    data
        (total,) uint8, read-only: the bytes of the files read whole, one after another (those
        visited from Python after the others).
    starts, sizes
        (n,) int64: where each file's bytes start in ``data`` and how many there are; size -1 for a
        file to read alone (larger than the limit, or not of the shared header) or that could not
        be opened.
    identities
        (n, 4) int64: each file's identity (:func:`.cache.file_identity`) from its open file's
        ``fstat``, for the store's key (:func:`.cache.files_key`); -1 for one not opened.
    errors
        {index: DatasetError} of the files that could not be opened (not found, outside the
        folder, not a file), for the caller to raise or report in their place in the manifest's
        order (each run carried its first error alone before: 10^6 missing frames made 10^6 runs).
    """

    data: np.ndarray
    starts: np.ndarray
    sizes: np.ndarray
    identities: np.ndarray
    errors: dict[int, DatasetError]

    def __len__(self) -> int:
        return len(self.sizes)


def read_run(resolver: FileResolver, names, header: bytes) -> FileRun:
    """Read the files ``names`` (the manifest's relative names) as the module docstring says, each
    whole when it starts with ``header`` (a file's bytes up to its chunk table)."""
    count = len(names)
    starts, sizes = np.zeros(count, np.int64), np.full(count, HANDED_BACK, np.int64)
    identities = np.full((count, IDENTITY_FIELDS), -1, np.int64)
    data, used, errors = np.empty(count * 2 * (len(header) + 64), np.uint8), 0, {}
    native = _native_run(resolver, names) if NATIVE_FILES and count else None
    if native is not None:  # the usual files, in one compiled call; it hands back any other
        try:
            data, used = read_files(native.folder, *native.names, native.inside, resolver.open_flags, HEAD_BYTES,
                                    np.frombuffer(header, np.uint8), data, used, starts, sizes, identities,
                                    native.scratch)
        finally:
            os.close(native.folder)
    for at in np.flatnonzero(sizes == HANDED_BACK).tolist():  # (every file, where there is no such call)
        starts[at], sizes[at] = used, -1
        try:
            whole, identities[at] = _read_alone(resolver, names[at], header)
        except DatasetError as problem:
            errors[at] = problem
            continue
        if whole is not None:
            if used + len(whole) > len(data):
                data = np.concatenate([data[:used], np.empty(max(len(data), len(whole)), np.uint8)])
            data[used:used + len(whole)] = np.frombuffer(whole, np.uint8)
            sizes[at] = len(whole)
            used += len(whole)
    data = data[:used]
    data.flags.writeable = False
    return FileRun(data, starts, sizes, identities, errors)


def reader_count() -> int:
    """Threads reading runs side by side: one a core (the compiled calls that visit the files, and
    those that check or decode them, release the GIL; so do OpenEXR's reader of whole files, and
    its selecting reader decodes on the library's own threads)."""
    return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class _NativeRun:
    """What :func:`.native_files.read_files` takes of a run: the dataset folder's descriptor, the
    encoded names, whether each one's folder is inside the dataset folder, and its scratch."""

    folder: int
    names: tuple[np.ndarray, np.ndarray]
    inside: np.ndarray
    scratch: np.ndarray


def _native_run(resolver: FileResolver, names) -> _NativeRun | None:
    """The :class:`_NativeRun` of ``names``, each folder checked once (the first name of each
    stretch of names of one folder); None when the names or the folder cannot be given to the
    compiled calls (every file is then visited from Python, which says what is wrong)."""
    encoded = encoded_names(names)
    if encoded is None:
        return None
    inside = np.empty(len(names), np.bool_)
    changes = folder_changes(*encoded).tolist()
    for at, stop in zip(changes, changes[1:] + [len(names)]):
        inside[at:stop] = resolver.folder_inside(names[at])
    folder = open_folder(resolver.folder)
    return None if folder is None else _NativeRun(folder, encoded, inside, new_scratch())


def _read_alone(resolver: FileResolver, name: str, header: bytes) -> tuple[bytes | None, tuple[int, ...]]:
    """File ``name`` visited from Python: its bytes when it is read whole and starts with
    ``header`` (else None), and its identity; DatasetError when it cannot be opened."""
    descriptor, _, status = resolver.open(name)
    size = status.st_size
    try:
        data = os.read(descriptor, size + 1) if size <= HEAD_BYTES else b""
    except OSError:
        data = b""  # read alone, which says why
    finally:
        os.close(descriptor)
    return (data if len(data) == size and data.startswith(header) else None), file_identity(status)
