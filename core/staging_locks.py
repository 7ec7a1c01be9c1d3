"""Locks on the staging folders of :mod:`.atomic`, and sweeping those their writers abandoned.

A writer holds an exclusive ``flock`` on its staging folder while it writes; the system releases
it when the process dies. A folder beside a private output (the dataset cache) named as a
staging folder, whose lock no process holds, was abandoned (a killed first open left gigabytes
beside the dataset) and :func:`sweep_abandoned` removes it. Without ``fcntl`` (not POSIX), or on a
file system without locks, nothing is locked and nothing is swept.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import time
from pathlib import Path

from .ownership import Owned, foreign_entry

try:
    import fcntl
except ImportError:  # not POSIX: no locks, so abandoned temporaries are never swept
    fcntl = None

NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL}
"""What ``flock`` says on a file system that has no locks."""
ABANDONED_AGE = 60.0
"""Seconds since a temporary folder was made or renamed before :func:`sweep_abandoned` may remove
it: a staging folder is locked just after it is made, so a younger one may be about to be."""


def lock_staging(folder: Path) -> int | None:
    """A descriptor of the new staging ``folder`` holding its lock (close it when done), or None
    without ``fcntl`` or on a file system without locks (where no sweep can lock it either).
    Raises OSError for any other failure (out of descriptors, say): unlocked, the folder would
    look abandoned to another process's sweep a minute on."""
    try:
        return _locked(folder)
    except OSError as error:
        if error.errno in NO_LOCKS:
            return None
        raise


def _locked(folder: Path) -> int | None:
    """A descriptor of ``folder`` holding its exclusive lock (None without ``fcntl``); raises
    OSError when it cannot be taken (BlockingIOError: another process holds it)."""
    if fcntl is None:
        return None
    descriptor = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BaseException:
        os.close(descriptor)
        raise
    return descriptor


def sweep_abandoned(final: str | os.PathLike, min_age: float | None = None,
                    kinds: tuple[str, ...] = ("partial", "old"), holds: Owned | None = None) -> list[str]:
    """Remove the hidden temporaries that writers of the private folder ``final`` abandoned: the
    real folders (never links or files) beside it named ``.NAME.partial-HEX`` or ``.NAME.old-HEX``
    for its NAME, made or renamed at least ``min_age`` seconds ago (default
    :data:`ABANDONED_AGE`), whose lock no process holds. Only for folders all of whose content is
    ringlight's (:func:`.atomic.atomic_folder`): an output's ``.old-HEX`` is the user's previous
    output. ``kinds`` narrows the names (``("partial",)``: only unfinished new outputs, as a
    capture's preparation leaves), and ``holds``, when given, is what such a folder may contain:
    one holding anything else is left alone. Returns the names removed; problems (a folder that
    vanished, one not ours to remove) are skipped."""
    if fcntl is None:
        return []
    final = Path(os.path.abspath(final))
    min_age = ABANDONED_AGE if min_age is None else min_age
    pattern = re.compile(re.escape(f".{final.name}.") + f"({'|'.join(kinds)})-[0-9a-f]{{12}}")
    removed = []
    try:
        with os.scandir(final.parent) as entries:
            names = [entry.name for entry in entries if pattern.fullmatch(entry.name)
                     and entry.is_dir(follow_symlinks=False)]
    except OSError:
        return []
    for name in names:
        folder = final.parent / name
        try:
            info = os.lstat(folder)
            if time.time() - max(info.st_mtime, info.st_ctime) < min_age:
                continue
            descriptor = _locked(folder)
        except OSError:  # gone, not a folder any more, or locked by its writer
            continue
        try:
            if holds is not None and foreign_entry(folder, holds) is not None:
                continue
            shutil.rmtree(folder)
            removed.append(name)
        except (OSError, RecursionError):  # RecursionError: a chain of folders deeper than rmtree recurses
            pass
        finally:
            os.close(descriptor)
    return removed
