"""Writing outputs without ever destroying user data: the one rule every writer follows.

**An output may replace only files ringlight itself wrote there, and never deletes anything else.**

Single files (PNG, MP4, CSV, JSON), :func:`atomic_file`
    Written to a hidden ``.NAME.partial-HEX.EXT`` beside the target and published by one rename.
    A target that exists (a file, or a link, even a dangling one) is refused unless the caller
    passes ``overwrite=True``: the window does after its save dialog asked the user, the command
    line does only with ``--force``. Without ``overwrite`` the file is published with a hard link,
    which fails if the name appeared meanwhile, so nothing is ever replaced by a race.

Folders (stack exports, datasets), :func:`output_folder`
    A folder output has a manifest that names its files (``stack.json`` its images,
    ``dataset.json`` its frames); the writer's ``owner`` function reads it. The new folder is
    built in a hidden ``.NAME.partial-HEX`` beside the target, then

    - an absent or empty target: the new folder is renamed into place (one rename);
    - a target holding an earlier output of the same kind, and nothing but the files its manifest
      names (:mod:`.ownership`), ringlight's own subfolders (``.ringlight-cache``, ``.scan``) and
      ringlight's hidden temporaries of those (``.NAME.partial-HEX.EXT`` is ringlight's only when
      ``NAME.EXT`` is: a user's ``.thesis.partial-0123456789ab.tex`` is the user's): the old
      folder is renamed aside,
      checked again (a file dropped in since the first check sends it back, untouched), the new
      one renamed in, and the old one deleted;
    - a target holding anything else (a ``thesis.tex``, an empty subfolder): refused with one line
      naming the folder and one such file; nothing is deleted, moved or merged. Refusing, rather
      than swapping only ringlight's files in, keeps every output whole (one rename publishes it)
      and leaves the user's files exactly where they were;
    - the current folder, a folder holding it, or a mount point: refused (a mount point cannot be
      renamed, and renaming the current folder would pull it from under the user's shell);
    - a symbolic link: the folder it points to is the target; a dangling link is refused.

Ringlight's private folders (the dataset cache) use :func:`atomic_folder`: the same mechanics, with
every file inside counted as ringlight's and a link in the folder's place removed, not followed.

Every error names the user's path, never a hidden temporary. A process killed outright leaves at
most a hidden ``.NAME.partial-HEX`` (an unfinished new output) and, if killed between the two
renames of a replacement, the previous output complete in a hidden ``.NAME.old-HEX``. A writer
holds a lock on its staging folder (``flock``, which the system releases when a process dies), so
that :func:`.staging_locks.sweep_abandoned` can tell a private folder's abandoned temporaries (a dataset cache's:
gigabytes a killed first open left beside the dataset) from one another process is writing now.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .errors import RinglightError
from .ownership import EVERYTHING, Owned, OwnerOf, foreign_entry
from .staging_locks import lock_staging

class OutputError(RinglightError):
    """An output cannot be written where it was asked for (the message says why and what to do)."""


@dataclass(frozen=True)
class _Target:
    shown: Path
    """The path as the user gave it: every message names this."""
    real: Path
    """Absolute, links resolved: every operation uses this."""


def _target(path: str | os.PathLike, follow: bool = True) -> _Target:
    """``path`` with its folders' links resolved, and its own name's too when ``follow`` (a user's
    output written through a link lands where the link points)."""
    shown = Path(path)
    absolute = Path(os.path.abspath(shown))  # "." and ".." become names that can be renamed
    if not follow:
        return _Target(shown, Path(os.path.realpath(absolute.parent)) / absolute.name)
    if absolute.is_symlink() and not absolute.exists():
        raise OutputError(f"{shown}: is a symbolic link to {os.readlink(absolute)}, which does not exist; "
                          "create that folder or give another path")
    return _Target(shown, Path(os.path.realpath(absolute)))


def _holds_current_folder(folder: Path) -> bool:
    try:
        current = Path(os.path.realpath(os.getcwd()))
    except OSError:  # the current folder was deleted
        return False
    return current == folder or folder in current.parents


def _check(target: _Target, owner: OwnerOf, kind: str, replace: bool) -> bool:
    """Raise OutputError unless ``target`` may receive the output; True when it exists."""
    real, shown = target.real, target.shown
    try:
        if not real.exists():
            _refuse_file_above(shown)  # before the work, not "File exists" after it
            return False
        if not real.is_dir():
            raise OutputError(f"{shown}: exists and is not a folder; refusing to overwrite it")
        if _holds_current_folder(real):
            raise OutputError(f"{shown}: is the current folder (or holds it); ringlight publishes a {kind} "
                              f"by renaming a new folder into place, so write it to a new folder, e.g. "
                              f"{shown / kind}")
        if os.path.ismount(real):
            raise OutputError(f"{shown}: is a mount point, which cannot be replaced; "
                              f"write to a folder inside it, e.g. {shown / kind}")
        owned = owner(real)
        if owned is None:
            foreign = foreign_entry(real, Owned())
            if foreign is not None:
                raise OutputError(f"{shown}: exists and is not a ringlight {kind} folder (it holds {foreign}); "
                                  "refusing to overwrite it: choose another folder")
            return True
        if not replace:
            raise OutputError(f"{shown}: already holds a {kind}; refusing to overwrite it "
                              "(pass overwrite, --overwrite on the command line, to replace it)")
        foreign = foreign_entry(real, owned)
        if foreign is not None:
            raise OutputError(f"{shown}: holds {foreign}, which ringlight did not write; refusing to "
                              f"overwrite the {kind}: move that file away or choose another folder")
    except OSError as error:
        raise _named(error, shown) from error
    return True


def check_output_folder(path: str | os.PathLike, owner: OwnerOf, kind: str, replace: bool = True) -> None:
    """Raise :class:`OutputError` unless :func:`output_folder` may write ``path``.

    Writers call this before long work, so that a refusal comes before minutes of computing.
    """
    _check(_target(path), owner, kind, replace)


@contextmanager
def output_folder(path: str | os.PathLike, owner: OwnerOf, kind: str, replace: bool = True) -> Iterator[Path]:
    """Yield a staging folder; on a clean exit it becomes ``path`` under the module's rule.

    Parameters
    ----------
    path
        The output folder as the user gave it.
    owner
        Reads an existing folder's manifest (see :data:`OwnerOf`).
    kind
        What the output is, for messages: ``"stack"``, ``"dataset"``.
    replace
        Whether an earlier output of this kind may be replaced (``False``: only an absent or
        empty folder is written).

    On any exception (KeyboardInterrupt included) the staging folder is removed and ``path`` is
    untouched; an OSError about the staging folder is raised as :class:`OutputError` naming
    ``path``.
    """
    yield from _output_folder(_target(path), owner, kind, replace)


def _output_folder(target: _Target, owner: OwnerOf, kind: str, replace: bool) -> Iterator[Path]:
    """:func:`output_folder`'s body, for a target already resolved."""
    _check(target, owner, kind, replace)
    staging = target.real.parent / f".{target.real.name}.partial-{secrets.token_hex(6)}"
    try:
        target.real.parent.mkdir(parents=True, exist_ok=True)
        # mkdir, not mkdtemp: the folder gets the user's usual permissions, not 0700.
        staging.mkdir()
    except OSError as error:
        raise _named(error, target.shown) from error
    try:
        lock = lock_staging(staging)
    except OSError as error:
        shutil.rmtree(staging, ignore_errors=True)
        raise _named(error, target.shown) from error
    try:
        try:
            yield staging
        except BaseException as error:
            raise _renamed(error, staging, target.shown)
        _publish(staging, target, owner, kind, replace)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        if lock is not None:
            os.close(lock)


@contextmanager
def atomic_folder(final: str | os.PathLike) -> Iterator[Path]:
    """:func:`output_folder` for ringlight's private folders (the cache): all inside is ours.

    A link planted under the private name is removed, never followed: the folder it points to
    is not ringlight's. The name itself is never resolved, so a link planted there while the
    folder is written (another process, between the removal and the publication) is what a
    rename moves aside and what is removed afterwards, never the folder it points to.
    """
    target = _target(final, follow=False)
    if target.real.is_symlink():
        try:
            target.real.unlink()
        except OSError as error:
            raise _named(error, target.shown) from error
    yield from _output_folder(target, lambda folder: EVERYTHING, "cache", True)


def _publish(staging: Path, target: _Target, owner: OwnerOf, kind: str, replace: bool) -> None:
    real, shown = target.real, target.shown
    try:
        if not _check(target, owner, kind, replace) or not any(real.iterdir()):
            os.rename(staging, real)  # onto an absent name or an empty folder: one atomic step
            return
        trash = real.parent / f".{real.name}.old-{secrets.token_hex(6)}"
        os.rename(real, trash)
        owned = owner(trash)
        foreign = foreign_entry(trash, owned if owned is not None else Owned())
        if foreign is not None:  # dropped in since the first check: put everything back
            os.rename(trash, real)
            raise OutputError(f"{shown}: {foreign} appeared while the {kind} was written; refusing to "
                              "overwrite the folder: move that file away and write again")
        try:
            os.rename(staging, real)
        except OSError:
            os.rename(trash, real)
            raise
        try:
            if trash.is_symlink():  # planted at a private folder's name: the link goes, never its folder
                trash.unlink()
            else:
                shutil.rmtree(trash, ignore_errors=True)
        except (OSError, RecursionError):  # a chain of folders deeper than rmtree recurses: left hidden
            pass
    except OSError as error:
        if error.errno in (errno.ENOTEMPTY, errno.EEXIST):
            raise OutputError(f"{shown}: files appeared in it while the {kind} was written; "
                              "nothing was overwritten: write again") from error
        raise _named(error, shown) from error


@contextmanager
def atomic_file(final: str | os.PathLike, *, overwrite: bool = False, make_parents: bool = True,
                durable: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``final`` (same suffix, so writers that pick a format by
    extension still work); on a clean exit it becomes ``final`` in one step.

    Parameters
    ----------
    final
        The file to write.
    overwrite
        Replace an existing ``final``; without it an existing name raises :class:`OutputError`,
        before anything is written.
    make_parents
        Create missing folders above ``final`` (``False``: a missing folder is an error, so that
        a folder deleted meanwhile is not silently made again).
    durable
        Flush the file and its folder to the disk before returning (survives a power cut).

    On any exception the temporary file is removed and ``final`` is untouched; an OSError about
    the temporary is raised as :class:`OutputError` naming ``final``.
    """
    final = Path(final)
    check_output_file(final, overwrite)
    # A fresh name, not a mkstemp file: the writer creates it with the user's usual permissions.
    temporary = _temporary_file(final)
    try:
        if make_parents:
            try:
                final.parent.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise _named(error, final) from error
        try:
            yield temporary
        except BaseException as error:
            raise _renamed(error, temporary, final)
        try:
            if durable:
                fsync_path(temporary)
            _publish_file(temporary, final, overwrite)
            if durable:
                fsync_path(final.parent)
        except OSError as error:
            raise _named(error, final) from error
    finally:
        try:
            temporary.unlink(missing_ok=True)
        except OSError:  # its folder is gone or not a folder: nothing of ours is left there
            pass


def check_output_file(final: str | os.PathLike, overwrite: bool = False, probe: bool = False,
                      overwrite_option: str = "--force") -> None:
    """Raise :class:`OutputError` unless :func:`atomic_file` may write ``final`` (call it before
    long work, so that a refusal comes first). With ``probe``, a hidden temporary is also created
    and removed in ``final``'s folder where that exists, so that a folder the user cannot write
    (``/proc``, a read-only mount) is refused before the work rather than after it. Something
    that is neither a file nor a link (a device such as ``/dev/null``, a FIFO, a socket) is never
    replaced, even with ``overwrite`` (the rename made ``/dev/null`` a file). The refusal of an
    existing file names the command line's ``overwrite_option``."""
    final = Path(final)
    try:
        if final.is_dir():
            raise OutputError(f"{final}: is a folder; give a file name")
        if os.path.lexists(final) and not final.is_symlink() and not final.is_file():
            raise OutputError(f"{final}: is not a file (a device, a FIFO or a socket); refusing to replace it; "
                              "give a file name")
        if os.path.lexists(final) and not overwrite:
            raise OutputError(f"{final}: already exists; refusing to overwrite it "
                              f"(choose another name, or allow overwriting: {overwrite_option} on the command line)")
        _refuse_file_above(final)
        if probe and final.parent.is_dir():
            temporary = _temporary_file(final)
            os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            os.unlink(temporary)
    except OSError as error:  # a name too long, a folder not searchable
        raise _named(error, final) from error


def _refuse_file_above(path: Path) -> None:
    """Raise :class:`OutputError` when the nearest existing entry above ``path`` is not a folder
    (``notes.txt/out``), which making ``path`` would fail at with "File exists"."""
    above = next((folder for folder in path.parents if os.path.lexists(folder)), None)
    if above is not None and not above.is_dir():
        raise OutputError(f"{path}: {above} is a file, not a folder; give another path")


NAME_MAX = 255
"""Bytes in one file name on the usual file systems (ext4, XFS, btrfs, APFS)."""


def _temporary_file(final: Path) -> Path:
    """A fresh hidden name beside ``final`` with its suffix (writers pick a format by extension).
    The stem is shortened where the hidden name would pass :data:`NAME_MAX`, so that every name
    the system accepts can be written (a 250-byte name otherwise failed as "too long")."""
    marker = f".partial-{secrets.token_hex(6)}{final.suffix}"
    room = NAME_MAX - 1 - len(marker.encode())
    stem = final.stem.encode()[:max(room, 1)].decode(errors="ignore")
    return final.parent / f".{stem}{marker}"


def _publish_file(temporary: Path, final: Path, overwrite: bool) -> None:
    if overwrite:
        os.replace(temporary, final)
        return
    try:
        os.link(temporary, final)  # fails if the name exists: never replaces a file created meanwhile
    except FileExistsError:
        raise OutputError(f"{final}: appeared while it was written; refusing to overwrite it") from None
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.EXDEV):
            raise
        check_output_file(final, overwrite)  # a file system without hard links: check, then rename
        os.replace(temporary, final)


def fsync_path(path: Path) -> None:
    """Flush a file's data, or a folder's entries, to the disk."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def _named(error: OSError, shown: Path) -> OutputError:
    """An OSError as one line naming the user's path (its file names may be hidden temporaries)."""
    reason = error.strerror or str(error)
    if error.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        reason += " (the folder is read-only for you)"
    return OutputError(f"{shown}: cannot write here: {reason}")


def _renamed(error: BaseException, temporary: Path, shown: Path) -> BaseException:
    """``error`` raised inside a staging block, with the hidden temporary's name replaced by the
    user's: OSError and library errors that name it become OutputError, ringlight's own errors
    keep their type; anything else is returned unchanged."""
    if isinstance(error, OSError) and (_names(error, temporary) or _is_full(error)):
        named = _named(error, shown)
    elif isinstance(error, (RinglightError, RuntimeError)) and str(temporary) in str(error):
        message = str(error).replace(str(temporary), str(shown))
        # The OpenEXR library reports a failed write (disk full) as RuntimeError.
        named = OutputError(message) if isinstance(error, RuntimeError) else type(error)(message)
    else:
        return error
    named.__cause__ = error
    return named


_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}
"""A full disk, a quota or a file-size limit: what a write says, with no file name."""


def _is_full(error: OSError) -> bool:
    """True for a write refused for space that names no file (``file.write`` raises it without
    one): inside a staging block it is the output's, so the message names the user's path."""
    return error.errno in _FULL and not error.filename


def _names(error: OSError, temporary: Path) -> bool:
    return any(str(name).startswith(str(temporary)) for name in (error.filename, error.filename2) if name)
