"""What ringlight wrote in an output folder, and whether a folder holds anything else.

An output folder's manifest names its files (:class:`Owned`); :func:`foreign_entry` finds an
entry of an existing folder that ringlight did not write, which :mod:`.atomic` then refuses to
replace. A hidden temporary of :mod:`.atomic` (``.NAME.partial-HEX[.EXT]``, ``.NAME.old-HEX``)
counts as ringlight's only when what it stands for does: a user's
``.thesis.partial-0123456789ab.tex`` is the user's.
"""

from __future__ import annotations

import fnmatch
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

_TEMPORARY = re.compile(r"\.(?P<name>.+)\.(partial|old)-[0-9a-f]{12}(?P<extension>\.[^/]*)?")
"""Names of :mod:`.atomic`'s hidden temporaries (``.NAME.partial-HEX[.EXT]``, ``.NAME.old-HEX``)."""


@dataclass(frozen=True)
class Owned:
    """What ringlight wrote in an output folder.

    Attributes
    ----------
    files
        Relative POSIX paths of the files (and folders) ringlight made; the folders leading to
        them count as ringlight's too, if all they hold is.
    trees
        :mod:`fnmatch` patterns of relative folder paths whose whole content is ringlight's
        (``".ringlight-cache"``).
    """

    files: frozenset[str] = frozenset()
    trees: tuple[str, ...] = ()

    def leads_to(self, relative: str) -> bool:
        """True when ``relative`` is a folder on the way to one of :attr:`files`."""
        return any(name.startswith(relative + "/") for name in self.files)

    def contains(self, relative: str) -> bool:
        """True when the file ``relative`` is one of :attr:`files` or lies inside one of
        :attr:`trees` (at any depth)."""
        parts = relative.split("/")
        return relative in self.files or any(fnmatch.fnmatchcase("/".join(parts[:end]), tree)
                                             for end in range(1, len(parts) + 1) for tree in self.trees)

    def holds(self, relative: str) -> bool:
        """True when the entry ``relative`` is one of :attr:`files`, inside one of :attr:`trees`,
        or on the way to one of the files."""
        return (relative in self.files or self.leads_to(relative)
                or any(fnmatch.fnmatchcase(relative, tree) for tree in self.trees))


OwnerOf = Callable[[Path], "Owned | None"]
"""Reads an existing folder's manifest: what ringlight wrote there, or None when the folder is
not an output of this kind."""

EVERYTHING = Owned(trees=("*",))
"""For ringlight's private folders: every entry is ringlight's."""


def is_temporary(name: str) -> bool:
    """True for the names of :mod:`.atomic`'s hidden temporaries (``.NAME.partial-HEX[.EXT]``)."""
    return _TEMPORARY.fullmatch(name) is not None


def temporary_of(name: str) -> str | None:
    """The name a hidden temporary stands for (``.stack.partial-HEX.json`` -> ``stack.json``,
    ``.frames.old-HEX`` -> ``frames``), or None for any other name."""
    match = _TEMPORARY.fullmatch(name)
    return None if match is None else match["name"] + (match["extension"] or "")


def foreign_entry(folder: Path, owned: Owned) -> str | None:
    """The relative path of one entry of ``folder`` that ringlight did not write, or None.

    A folder named in ``owned.files`` or leading to one is walked: what it holds must be
    ringlight's too. A hidden temporary is ringlight's when what it stands for is
    (:func:`temporary_of`). Links are never followed (a link is an entry like a file); the walk stops at
    the first foreign entry, so a huge folder costs little.
    """
    def walk(directory: Path, prefix: str) -> str | None:
        with os.scandir(directory) as entries:
            for entry in sorted(entries, key=lambda entry: entry.name):
                relative = prefix + entry.name
                target = temporary_of(entry.name)
                if any(fnmatch.fnmatchcase(relative, tree) for tree in owned.trees) or (
                        target is not None and owned.holds(prefix + target)):
                    continue
                if entry.is_dir(follow_symlinks=False):
                    if relative in owned.files or owned.leads_to(relative):
                        found = walk(Path(entry.path), relative + "/")
                        if found is None:
                            continue
                        return found
                elif relative in owned.files:
                    continue
                return relative
        return None
    return walk(folder, "")
