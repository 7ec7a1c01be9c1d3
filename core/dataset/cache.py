"""Where a dataset's store lives and the key that tells whether it is current.

The store itself (chunked, compressed, checksummed responses) is :mod:`.response_store`; an entry
is used only when its key matches: a hash of everything in the manifest the responses depend on;
the size, mtime, inode and ctime of every frame, dark and mapping file; the effective max radius
and the layout version. The ctime changes whenever a file is replaced or its mtime is set back,
so a frame swapped for another of the same size is noticed.

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
from .response_store import LAYOUT_VERSION

CACHE_FOLDER_NAME = ".ringlight-cache"


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
    digest.update("\0".join(frames.files).encode("utf-8"))
    digest.update(np.ascontiguousarray(frames.counts, np.int64).tobytes())
    digest.update(np.ascontiguousarray(frames.lit, np.int64).tobytes())
    digest.update(np.ascontiguousarray(frames.exposures, np.float64).tobytes())
    prefix = os.path.join(str(manifest.folder), "")
    for name in manifest.referenced_files():
        try:
            info = os.stat(prefix + name)
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
