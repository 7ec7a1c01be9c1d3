"""Reading a run of a dataset's small files whole, in one buffer, for one compiled pass over them.

A long manifest's frames are small files that share one header (one camera, one writer): what
each costs in Python is its system calls. :func:`read_run` opens each file of a run once
(:meth:`.file_paths.FileResolver.open`: located, checked inside the dataset folder and opened in
one call), reads it whole in one ``read`` when it has at most :data:`.exr_chunks.HEAD_BYTES` and
starts with the header bytes the run shares, and closes it. The bytes of all the files go into one
array, each file's at its offset, which a compiled pass then checks (:mod:`.checks`) or decodes
(:mod:`.frame_batch`) in one call. A file that does not start with the shared header, or is
larger, is marked for its caller to read alone, as before (its problem, if it has one, is then
said as it always was); a file that cannot be opened ends the run there, its error kept for the
caller to raise or report in its place, so that problems keep the manifest's order.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import DatasetError
from .cache import IDENTITY_FIELDS, file_identity
from .exr_chunks import HEAD_BYTES
from .file_paths import FileResolver


@dataclass(frozen=True, eq=False)
class FileRun:
    """The files of a run read (see the module docstring), ``n`` of them, fewer than asked when
    one could not be opened.

    Attributes
    ----------
    data
        (total,) uint8, read-only: the bytes of the files read whole, one after another.
    starts, sizes
        (n,) int64: where each file's bytes start in ``data`` and how many there are; size -1 for a
        file to read alone (larger than the limit, or not of the shared header).
    identities
        (n, 4) int64: each file's identity (:func:`.cache.file_identity`) from its open file's
        ``fstat``, for the store's key (:func:`.cache.files_key`).
    error
        The DatasetError of the file after the last one read (not found, outside the folder, not
        a file), or None when the run was read to its end.
    """

    data: np.ndarray
    starts: np.ndarray
    sizes: np.ndarray
    identities: np.ndarray
    error: DatasetError | None

    def __len__(self) -> int:
        return len(self.sizes)


def read_run(resolver: FileResolver, names, header: bytes) -> FileRun:
    """Read the files ``names`` (the manifest's relative names) as the module docstring says, each
    whole when it starts with ``header`` (a file's bytes up to its chunk table)."""
    pieces, sizes, identities = [], [], []
    error = None
    limit = HEAD_BYTES
    for name in names:
        try:
            descriptor, _, status = resolver.open(name)
        except DatasetError as problem:
            error = problem
            break
        size = status.st_size
        try:
            data = os.read(descriptor, size + 1) if size <= limit else b""
        except OSError:
            data = b""  # read alone, which says why
        finally:
            os.close(descriptor)
        if len(data) == size and data.startswith(header):
            pieces.append(data)
            sizes.append(size)
        else:
            sizes.append(-1)
        identities.append(file_identity(status))
    sizes = np.array(sizes, np.int64)
    starts = np.zeros(len(sizes), np.int64)
    if len(sizes) > 1:
        np.cumsum(np.maximum(sizes[:-1], 0), out=starts[1:])
    return FileRun(np.frombuffer(b"".join(pieces), np.uint8), starts, sizes,
                   np.array(identities, np.int64).reshape(-1, IDENTITY_FIELDS), error)
