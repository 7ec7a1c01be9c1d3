"""Where a manifest's files are, checked to stay inside the dataset folder, with each folder on
the way resolved once: ``Path.resolve`` of every frame walked every component of its path with
``lstat`` (20 s of the 30 s ``info`` took over a 100 000-frame manifest).

A file's path is its resolved folder (cached per folder: ``frames/`` once) joined with its name,
unless the name itself is a symbolic link, which is then resolved whole. That is what
``Path.resolve`` gives, with one ``lstat`` per file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ..errors import DatasetError


class FileResolver:
    """``resolver(name)``: the path of the dataset file ``name`` (relative, '/'-separated, as the
    manifest holds it), refused with DatasetError when it resolves outside ``folder`` unless
    ``allow_outside`` (for labs that keep frames on another disk and link them in). Works on
    strings (``pathlib`` made its own work the larger part) and makes one Path a file."""

    def __init__(self, folder: Path, allow_outside: bool = False):
        self.folder = Path(folder)
        self.allow_outside = allow_outside
        self._prefix = os.path.join(str(self.folder), "")
        self._root: str | None = None
        self._folders: dict[str, str] = {}
        self._inside: set[str] = set()  # folders whose real path is the dataset folder or inside it

    def __call__(self, name: str) -> Path:
        return Path(self.locate(name))

    def locate(self, name: str) -> str:
        """The path of ``name`` as a string (what :meth:`__call__` makes a Path of): a pass over
        100 000 frames need not build a Path each."""
        path = self._prefix + name
        if not self.allow_outside:
            self._check_inside(path, self._resolved)
        return path

    def _check_inside(self, path: str, real_of) -> None:
        """DatasetError unless ``real_of(path)``, the real path of ``path``, is inside the folder."""
        try:
            if self._root is None:
                self._root = os.path.realpath(self.folder)
            real = real_of(path)
        except (OSError, RuntimeError) as error:  # RuntimeError: a symbolic-link loop
            raise DatasetError(f"{Path(path)}: cannot be resolved "
                               f"({getattr(error, 'strerror', None) or error})") from None
        if not (real == self._root or real.startswith(os.path.join(self._root, ""))):
            raise DatasetError(f"{Path(path)}: resolves to {real}, outside the dataset folder {self._root}; "
                               "allow files outside it explicitly (--allow-outside) to read it")

    def _resolved(self, path: str) -> str:
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            mode = None
        except OSError:  # not a folder on the way, a name too long: as Path.resolve says it
            return str(Path(path).resolve())
        if mode is not None and stat.S_ISLNK(mode):
            return str(Path(path).resolve())
        return self._in_real_folder(path)

    def _in_real_folder(self, path: str) -> str:
        """``path`` with its folder resolved (once per folder): its real path when it is no link."""
        parent, _, base = path.rpartition("/")
        if parent not in self._folders:
            real = self._folders[parent] = str(Path(parent).resolve())
            if real == self._root or real.startswith(os.path.join(self._root, "")):
                self._inside.add(parent)
        return os.path.join(self._folders[parent], base)

    def _check_in_folder(self, path: str) -> None:
        """:meth:`_check_inside` of a file that is no link, whose real path is its folder's: a
        set lookup for a file of a folder already known to be inside."""
        if path.rpartition("/")[0] not in self._inside:
            self._check_inside(path, self._in_real_folder)

    @property
    def open_flags(self) -> int:
        """The flags :meth:`open` opens a file with: read only, never waiting on a FIFO, not
        inherited, and not following a last link unless files may lie outside the folder."""
        flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC
        return flags if self.allow_outside else flags | os.O_NOFOLLOW

    def folder_inside(self, name: str) -> bool:
        """Whether the folder of ``name`` is known to resolve inside the dataset folder (resolved
        once a folder), or files may lie outside it: a file of it that is no link is then inside.
        False also when the folder cannot be resolved: :meth:`open` says why."""
        if self.allow_outside:
            return True
        try:
            self._check_in_folder(self._prefix + name)
        except DatasetError:
            return False
        return True

    def open(self, name: str) -> tuple[int, str, os.stat_result]:
        """``(descriptor, path, status)``: the dataset file ``name`` opened for reading (never
        waiting on a FIFO), checked as :meth:`locate` checks it, in one system call for a file that
        is not a link: opened without following a last link, its real path is its folder's,
        resolved once. ``status`` is the open file's ``fstat`` (its size, and its identity for the
        store's key: :func:`.cache.file_identity`). Raises DatasetError naming it: outside the
        folder, not found, not readable, not a file."""
        path = self._prefix + name
        flags = self.open_flags
        if self.allow_outside:
            descriptor = _opened(path, flags)
        else:
            try:
                descriptor = os.open(path, flags)
            except FileNotFoundError:  # no such file (nor link): said once its folder is known inside
                self._check_in_folder(path)
                raise DatasetError(f"{os.path.normpath(path)}: file not found") from None
            except OSError:  # a link (ELOOP) and the like: resolved first, as locate does
                descriptor = _opened(self.locate(name), flags & ~os.O_NOFOLLOW)
            else:
                try:
                    self._check_in_folder(path)
                except BaseException:
                    os.close(descriptor)
                    raise
        status = os.fstat(descriptor)
        if not stat.S_ISREG(status.st_mode):
            os.close(descriptor)
            raise DatasetError(f"{os.path.normpath(path)}: not a file")
        return descriptor, path, status


def _opened(path: str, flags: int) -> int:
    """``os.open(path, flags)``, its errors one line naming the path."""
    try:
        return os.open(path, flags)
    except FileNotFoundError:
        raise DatasetError(f"{os.path.normpath(path)}: file not found") from None
    except OSError as error:
        raise DatasetError(f"{os.path.normpath(path)}: cannot be read ({error.strerror or error})") from None
