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

    def __call__(self, name: str) -> Path:
        return Path(self.locate(name))

    def locate(self, name: str) -> str:
        """The path of ``name`` as a string (what :meth:`__call__` makes a Path of): a pass over
        100 000 frames need not build a Path each."""
        path = self._prefix + name
        if not self.allow_outside:
            try:
                if self._root is None:
                    self._root = os.path.realpath(self.folder)
                real = self._resolved(path)
            except (OSError, RuntimeError) as error:  # RuntimeError: a symbolic-link loop
                raise DatasetError(f"{Path(path)}: cannot be resolved "
                                   f"({getattr(error, 'strerror', None) or error})") from None
            if not (real == self._root or real.startswith(os.path.join(self._root, ""))):
                raise DatasetError(f"{Path(path)}: resolves to {real}, outside the dataset folder {self._root}; "
                                   "allow files outside it explicitly (--allow-outside) to read it")
        return path

    def _resolved(self, path: str) -> str:
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            mode = None
        except OSError:  # not a folder on the way, a name too long: as Path.resolve says it
            return str(Path(path).resolve())
        if mode is not None and stat.S_ISLNK(mode):
            return str(Path(path).resolve())
        parent, _, base = path.rpartition("/")
        if parent not in self._folders:
            self._folders[parent] = str(Path(parent).resolve())
        return os.path.join(self._folders[parent], base)
