"""Packed cache of a dataset's response array, so that a second open skips EXR decoding.

A cache entry is a folder with ``responses.npy``, ``lit_counts.npy``, ``observed.npy`` and
``meta.json``. ``meta.json`` holds the key (a hash of everything in the manifest the responses
depend on; the size, mtime, inode and ctime of every frame, dark and mapping file; the effective
max radius and this module's layout version) and a CRC-32 of each array file. The ctime changes whenever a file is replaced or
its mtime is set back, so a frame swapped for another of the same size is noticed. An entry whose
key differs, or whose files fail their checks (not regular files, missing, truncated, wrong header,
wrong CRC, a meta.json of the wrong shape, arrays of another shape or type than the dataset's),
is ignored and rebuilt: a cache is never trusted, and a
FIFO, device or symbolic link planted in it is never opened.

Entries live in ``DATASET/.ringlight-cache`` when the dataset folder is writable, else under the
user cache folder (``$RINGLIGHT_CACHE_DIR``, else ``$XDG_CACHE_HOME/ringlight``, else
``~/.cache/ringlight``) in a folder named by a hash of the dataset's absolute path.
Entries are written to a temporary folder and renamed into place, so a crash leaves none half-written.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_folder
from ..errors import RinglightError
from ..validation import read_json
from .manifest import Manifest

LAYOUT_VERSION = 1
CACHE_FOLDER_NAME = ".ringlight-cache"
_ARRAYS = ("responses", "lit_counts", "observed")


@dataclass(frozen=True, eq=False)
class CachedArrays:
    """The arrays a dataset open produces. ``responses`` may be a read-only memory map."""

    responses: np.ndarray
    lit_counts: np.ndarray
    observed: np.ndarray


def user_cache_root() -> Path:
    """The per-user cache folder of ringlight (not created)."""
    if os.environ.get("RINGLIGHT_CACHE_DIR"):
        return Path(os.environ["RINGLIGHT_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ringlight"


def cache_key(manifest: Manifest, max_radius: float) -> str:
    """Hash of everything the response array depends on (see the module docstring).

    The manifest is hashed by content, not by its file, so a :class:`Manifest` built in memory
    or a manifest file replaced since it was read cannot reuse another dataset's entry.
    """
    digest = hashlib.sha256()
    digest.update(f"layout {LAYOUT_VERSION} radius {max_radius!r} grid {manifest.height} {manifest.width} "
                  f"{manifest.frame_space} {manifest.mapping!r} {manifest.dark!r} {manifest.channels!r} "
                  f"{manifest.part!r} {manifest.colorspace!r}\n".encode())
    frames = manifest.frames
    digest.update("\0".join(frame.file for frame in frames).encode("utf-8"))
    digest.update(np.array([len(frame.lit) for frame in frames], np.int64).tobytes())
    digest.update(np.concatenate([frame.lit for frame in frames]).astype(np.int64).tobytes())
    digest.update(np.array([frame.exposure for frame in frames], np.float64).tobytes())
    for name in manifest.referenced_files():
        try:
            info = (manifest.folder / name).stat()
            digest.update(f"\n{name} {info.st_size} {info.st_mtime_ns} {info.st_ino} {info.st_ctime_ns}".encode())
        except OSError:
            digest.update(f"\n{name} missing".encode())
    return digest.hexdigest()


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


def load_cache(location: Path, key: str,
               expected: dict[str, tuple[tuple[int, ...], np.dtype]] | None = None) -> CachedArrays | None:
    """Return the cached arrays for ``key``, or None when absent, stale or corrupt.

    ``expected`` maps array names to the ``(shape, dtype)`` the dataset needs; an entry whose
    arrays differ is not used. Only regular files are opened (never a link, FIFO or device).
    """
    try:
        if not stat.S_ISDIR(os.lstat(location).st_mode):
            return None
        if not stat.S_ISREG(os.lstat(location / "meta.json").st_mode):
            return None
        meta = read_json(location / "meta.json", _CacheInvalid, "cache meta.json", max_bytes=2**16)
        if not isinstance(meta, dict) or meta.get("key") != key:
            return None
        crc32, shapes = meta.get("crc32"), meta.get("shapes")
        if not isinstance(crc32, dict) or not isinstance(shapes, dict):
            return None
        arrays = {}
        for name in _ARRAYS:
            path = location / f"{name}.npy"
            if not stat.S_ISREG(os.lstat(path).st_mode) or _crc32(path) != crc32.get(name):
                return None
            arrays[name] = np.load(path, mmap_mode="r" if name == "responses" else None, allow_pickle=False)
            if list(arrays[name].shape) != shapes.get(name):
                return None
            if expected is not None and (arrays[name].shape, arrays[name].dtype) != expected[name]:
                return None
    except (OSError, ValueError, EOFError, _CacheInvalid):
        return None
    return CachedArrays(**arrays)


class _CacheInvalid(RinglightError):
    """A cache file that cannot be used; the cache is rebuilt, so users never see this."""


def save_cache(location: Path, key: str, arrays: CachedArrays) -> bool:
    """Write a cache entry atomically; returns False (and leaves nothing) when it cannot.

    Nothing is written when ``location`` exists as anything but a real folder: replacing it would
    follow a symbolic link to whatever folder it names.
    """
    try:
        if not stat.S_ISDIR(os.lstat(location).st_mode):
            return False
    except FileNotFoundError:
        pass
    except OSError:
        return False
    try:
        with atomic_folder(location) as staging:
            meta = {"key": key, "layout": LAYOUT_VERSION, "crc32": {}, "shapes": {}}
            for name in _ARRAYS:
                array = getattr(arrays, name)
                path = staging / f"{name}.npy"
                np.save(path, array, allow_pickle=False)
                meta["crc32"][name] = _crc32(path)
                meta["shapes"][name] = list(array.shape)
            (staging / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    except (OSError, RinglightError):  # the output rule refused the folder (a mount point, ...)
        return False
    return True


def _crc32(path: Path, chunk: int = 1 << 24) -> int:
    crc = 0
    # O_NOFOLLOW and O_NONBLOCK: a symbolic link or FIFO put in place of a cache file is refused.
    descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        raise OSError(f"{path} is not a regular file")
    with os.fdopen(descriptor, "rb") as handle:
        while block := handle.read(chunk):
            crc = zlib.crc32(block, crc)
    return crc
