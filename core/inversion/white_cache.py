"""The user cache of white Monte Carlo databases: one ``<key>.npz`` per optics, photon count and
seed in ``<user cache>/white`` (:func:`ringlight.core.dataset.cache.user_cache_root`), the least
recently used dropped once the databases there take more than :func:`cache_limit` bytes.

A structure search makes a database for every scattering coefficient and thickness it tries
(14-43 MB each at 20 000 photons), so without a limit the folder only grows: 189 databases and
6.6 GiB after a few evaluations on this machine. A database that is loaded is marked as used
(its modification time set to now), so the ones a search keeps needing stay.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

from ..checked_arrays import save_checked
from ..dataset.cache import user_cache_root
from ..dataset.memory import size_setting
from ..errors import RinglightError

CACHE_BYTES = 4 * 2**30
"""Default limit of the databases' total size (``$RINGLIGHT_WHITE_CACHE`` overrides: ``2G``)."""
_DATABASE_NAME = re.compile(r"[0-9a-f]{24}\.npz")
"""What ringlight names a database: the only files the limit counts and deletes."""


def cache_folder() -> Path:
    return user_cache_root() / "white"


def cache_limit() -> int:
    """Bytes the databases may take together: ``$RINGLIGHT_WHITE_CACHE`` or :data:`CACHE_BYTES`.
    Raises RinglightError naming the variable when it is not a size."""
    return size_setting("RINGLIGHT_WHITE_CACHE", CACHE_BYTES)


def mark_used(path: Path) -> None:
    """Set ``path``'s modification time to now (a read-only cache is left as it is)."""
    try:
        os.utime(path)
    except OSError:
        pass


def store(path: Path, key: str, arrays: dict, limit: int) -> None:
    """Write ``arrays`` to ``path`` checked with ``key`` (:func:`ringlight.core.checked_arrays.save_checked`,
    atomically), then drop the databases used longest ago down to ``limit`` bytes (:func:`evict`).
    An unwritable cache is skipped: it only costs the next run its time."""
    try:
        save_checked(path, key, arrays)
    except (OSError, RinglightError):
        return
    evict(path.parent, path, limit)


def evict(folder: Path, keep: Path, limit: int) -> list[Path]:
    """Delete the databases in ``folder`` used longest ago (modification time) until those left
    take at most ``limit`` bytes; ``keep``, the one just written, stays whatever its size. Only
    regular files named as ringlight names databases are counted or deleted (never a link, a
    folder or another file). Returns the deleted paths; a file that cannot be deleted is skipped."""
    entries = []
    try:
        with os.scandir(folder) as listing:
            for entry in listing:
                if not _DATABASE_NAME.fullmatch(entry.name):
                    continue
                try:
                    status = entry.stat(follow_symlinks=False)
                except OSError:
                    continue
                if stat.S_ISREG(status.st_mode):
                    entries.append((status.st_mtime_ns, entry.name, status.st_size))
    except OSError:
        return []
    total = sum(size for *_, size in entries)
    deleted = []
    for _, name, size in sorted(entries):
        if total <= limit:
            break
        path = folder / name
        if path == keep:
            continue
        try:
            path.unlink()
        except OSError:
            continue
        total -= size
        deleted.append(path)
    return deleted
