"""Atomic creation of output folders: build beside the target, then rename into place."""

from __future__ import annotations

import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_folder(final: str | os.PathLike) -> Iterator[Path]:
    """Yield a staging folder beside ``final``; on a clean exit it replaces ``final``.

    On any exception (KeyboardInterrupt included) the staging folder is removed and ``final`` is
    untouched. A process killed outright leaves only a hidden ``.NAME.partial-*`` folder, never a
    half-written ``final``. Callers decide beforehand whether replacing ``final`` is allowed.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    # mkdir, not mkdtemp: the folder gets the user's usual permissions, not 0700.
    staging = final.parent / f".{final.name}.partial-{secrets.token_hex(6)}"
    staging.mkdir()
    try:
        yield staging
        replace_folder(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def replace_folder(new: Path, final: Path) -> None:
    """Move folder ``new`` to ``final``, replacing any folder there; ``final`` is never partial."""
    if final.exists():
        trash = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
        os.rename(final, trash / final.name)
        try:
            os.rename(new, final)
        except OSError:
            os.rename(trash / final.name, final)
            raise
        finally:
            shutil.rmtree(trash, ignore_errors=True)
    else:
        os.rename(new, final)


@contextmanager
def atomic_file(final: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``final`` (same suffix, so writers that pick a format by
    extension still work); on a clean exit it replaces ``final`` in one rename.

    On any exception the temporary file is removed and ``final`` is untouched.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    # A fresh name, not a mkstemp file: the writer creates it with the user's usual permissions.
    temporary = final.parent / f".{final.stem}.partial-{secrets.token_hex(6)}{final.suffix}"
    try:
        yield temporary
        os.replace(temporary, final)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
