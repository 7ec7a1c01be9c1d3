"""Where a dataset's store lives and the key that tells whether it is current.

The store itself (chunked, compressed, checksummed responses) is :mod:`.response_store`; an entry
is used only when its key matches: a hash of everything in the manifest the responses depend on
(:func:`manifest_key`: the effective max radius and the layout version with it), and of the size,
mtime, inode and ctime of every frame, dark and mapping file (:func:`files_key`). The ctime
changes whenever a file is replaced or its mtime is set back, so a frame swapped for another of the
same size is noticed.

The key is made in two parts so that each frame file is visited once by an open. An entry records
its manifest key too: when the dataset's entry is of another manifest (or there is none), nothing
can be reused and no file is stat'ed; a first open reads the frames, and the files' part of the key
comes from the ``fstat`` of each file as it was read (:mod:`.file_batch`). Only when the entry is of
this manifest are the files stat'ed (:func:`frame_identities`), to tell whether it is current.

Entries live in ``DATASET/.ringlight-cache`` when the dataset folder is writable, else under the
user cache folder (``$RINGLIGHT_CACHE_DIR``, else ``$XDG_CACHE_HOME/ringlight``, else
``~/.cache/ringlight``) in a folder named by a hash of the dataset's absolute path.
"""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

import numpy as np

from .manifest import Manifest
from .native_files import NATIVE_FILES, encoded_names, new_scratch, open_folder, stat_files
from .response_store import LAYOUT_VERSION

CACHE_FOLDER_NAME = ".ringlight-cache"
IDENTITY_FIELDS = 4
"""Columns of a file's identity (:func:`file_identity`)."""


def user_cache_root() -> Path:
    """The per-user cache folder of ringlight (not created)."""
    if os.environ.get("RINGLIGHT_CACHE_DIR"):
        return Path(os.environ["RINGLIGHT_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ringlight"


def stat_key(manifest: Manifest, manifest_digest: str) -> str:
    """The key of a store of ``manifest`` (of :func:`manifest_key` ``manifest_digest``), every
    referenced file stat'ed: whether an entry of this manifest is current."""
    return files_key(manifest_digest, frame_identities(manifest), other_identities(manifest))


def manifest_key(manifest: Manifest, max_radius: float) -> str:
    """Hash of everything in the manifest the response array depends on, and of the radius and the
    store's layout; no file is read.

    The manifest is hashed by content, not by its file, so a :class:`Manifest` built in memory
    or a manifest file replaced since it was read cannot reuse another dataset's entry.
    """
    digest = hashlib.sha256()
    digest.update(f"layout {LAYOUT_VERSION} radius {max_radius!r} grid {manifest.height} {manifest.width} "
                  f"{manifest.frame_space} {manifest.mapping!r} {manifest.dark!r} {manifest.channels!r} "
                  f"{manifest.part!r} {manifest.colorspace!r}\n".encode())
    frames = manifest.frames
    digest.update("\0".join(frames.files).encode("utf-8"))
    digest.update(np.ascontiguousarray(frames.counts, np.int64).tobytes())
    digest.update(np.ascontiguousarray(frames.lit, np.int64).tobytes())
    digest.update(np.ascontiguousarray(frames.exposures, np.float64).tobytes())
    return digest.hexdigest()


def files_key(manifest_digest: str, frames: np.ndarray, others: np.ndarray) -> str:
    """The key of a store: ``manifest_digest`` (:func:`manifest_key`) and the identities of the
    frame files ((F, 4) int64, :func:`file_identity`) and of the dark and mapping files
    (:func:`other_identities`)."""
    digest = hashlib.sha256(manifest_digest.encode())
    digest.update(np.ascontiguousarray(frames, np.int64).tobytes())
    digest.update(np.ascontiguousarray(others, np.int64).tobytes())
    return digest.hexdigest()


def file_identity(info: os.stat_result) -> tuple[int, int, int, int]:
    """Which file a status is of, as the key holds it: size, mtime (ns), inode, ctime (ns)."""
    return info.st_size, info.st_mtime_ns, info.st_ino, info.st_ctime_ns


def frame_identities(manifest: Manifest) -> np.ndarray:
    """(F, 4) int64 :func:`file_identity` of every frame file, stat'ed (following links, as
    reading does); -1 for one that cannot be."""
    return _identities(manifest.folder, manifest.frames.files)


def other_identities(manifest: Manifest) -> np.ndarray:
    """(2, 4) int64 :func:`file_identity` of the dark and mapping files; 0 for one the manifest
    does not name, -1 for one that cannot be stat'ed."""
    identities = np.zeros((2, IDENTITY_FIELDS), np.int64)
    for row, name in enumerate((manifest.dark, manifest.mapping)):
        if name is not None:
            identities[row] = _identities(manifest.folder, [name])[0]
    return identities


def _identities(folder: Path, names: list[str]) -> np.ndarray:
    """(len(names), 4) int64 identities of the files ``names`` of ``folder``, stat'ed; rows made
    :data:`STAT_ROWS` at a time (a Python tuple a file took 200 bytes: 200 MB for a million), by
    one compiled call a block where it can (:func:`.native_files.stat_files`: a few microseconds of
    Python a file less), any file it cannot answer stat'ed from Python."""
    prefix = os.path.join(str(folder), "")
    identities = np.empty((len(names), IDENTITY_FIELDS), np.int64)
    descriptor = open_folder(folder) if NATIVE_FILES else None
    scratch = new_scratch()
    try:
        for start in range(0, len(names), STAT_ROWS):
            block, rows = names[start:start + STAT_ROWS], identities[start:start + STAT_ROWS]
            encoded = encoded_names(block) if descriptor is not None else None
            missed = np.ones(len(block), np.bool_)
            if encoded is not None:
                stat_files(descriptor, *encoded, rows, missed, scratch)
            for at in np.flatnonzero(missed).tolist():
                try:
                    rows[at] = file_identity(os.stat(prefix + block[at]))
                except OSError:
                    rows[at] = -1
    finally:
        if descriptor is not None:
            os.close(descriptor)
    return identities


STAT_ROWS = 4096
"""Files stat'ed into one block of rows of :func:`_identities`."""


def cache_location(dataset_folder: Path) -> Path:
    """Where the cache of a dataset lives: inside it when writable, else in the user cache.

    A ``.ringlight-cache`` that is anything but a real folder (a symbolic link above all: saving
    replaces the cache folder whole, which must never reach a folder of the user's) sends the
    cache to the user cache folder.
    """
    folder = dataset_folder.resolve()
    inside = folder / CACHE_FOLDER_NAME
    try:
        mode = os.lstat(inside).st_mode
    except FileNotFoundError:
        mode = None
    except OSError:
        mode = 0
    if mode is not None and stat.S_ISDIR(mode) and os.access(inside, os.W_OK | os.X_OK):
        return inside
    if mode is None and os.access(folder, os.W_OK | os.X_OK):
        return inside
    tag = hashlib.sha256(str(folder).encode()).hexdigest()[:16]
    return user_cache_root() / f"{folder.name}-{tag}"
