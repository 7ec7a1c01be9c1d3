"""numba's cache of ringlight's kernels, kept true to the sources they were compiled from.

numba stamps a kernel's cache entry with its own file's source alone: a kernel that calls or
inlines a function of another module, or reads one of its constants (numba freezes globals), keeps
running the code compiled before that module changed. numba documents this ("cache invalidation
fails to recognize changes in symbols defined in a different file"); on numba 0.68.1 a cached
``f`` calling ``g`` of another file still returned the old ``g``'s result after ``g``'s file
changed, for a called, an inlined and a constant alike (``tests/test_kernel_cache.py``). README's
editable install meets it at every ``git pull`` that changes a callee but not its caller: the
maps, stacks and simulations would silently follow the old code.

So every process of ringlight checks, when ``ringlight.core`` is first imported and before any
kernel loads, a stamp kept where numba caches ringlight's kernels: a fingerprint of the sources a
kernel can reach (:func:`kernel_sources`: every module of ``ringlight.core`` that uses numba, and
every module those import, transitively). When the fingerprint differs, ringlight's entries
(numba's ``.nbi`` and ``.nbc`` files of ringlight's modules, nothing else) are removed from those
folders and the new stamp written; numba then compiles afresh, as on a fresh install
(:mod:`.compile_ahead`). A process that finds its sources' sizes and modification times as the
stamp recorded them reads no source (3.5 ms on this project's machines); one that finds them changed but the
reachable sources' contents the same (a checkout that only touched files) keeps the cache.

Where numba caches (its locators' order): ``NUMBA_CACHE_DIR`` when set, else each source folder's
``__pycache__`` when ringlight's is writable (README's editable install, a virtual environment),
else numba's per-user folder (an install ringlight cannot write to; finding it imports numba,
about half a second, which such a process's first kernel does anyway). In the first and last, a
subfolder per source folder, named for the folder and its path's SHA-1 as numba names it.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path

from .atomic import atomic_file
from .errors import RinglightError

_THIS_FILE = Path(os.path.abspath(__file__))
PACKAGE = _THIS_FILE.parent
"""``ringlight.core``'s folder: the kernels and every module they can reach live in it (its path made
absolute as numba makes a kernel's file's, links not resolved)."""
STAMP_NAME = "ringlight-kernels.json"
_USES_NUMBA = re.compile(r"^\s*(import|from)\s+numba\b", re.MULTILINE)
_IMPORT = re.compile(r"^\s*from\s+(\.+)([\w.]*)\s+import\s+(\([^)]*\)|[^\n]*)", re.MULTILINE)
"""A relative import (ringlight's modules import each other only so) and its names: the rest of the
line, or a bracket's lines."""


def is_cached(kernel) -> bool:
    """Whether numba's cache holds ``kernel`` (a dispatcher made with ``cache=True``) already: the
    index file numba names after its module and function (``<module>.<function>-<line>.py<version>.nbi``)
    in its cache folder. False on a fresh install (or after an update) until its first call has
    compiled it; True where numba caches nothing (no folder to look in). Reads no numba state but
    the dispatcher's own, so it costs a folder listing."""
    folder = kernel.stats.cache_path
    if not folder:
        return True
    module = kernel.py_func.__module__.rsplit(".", 1)[-1]
    return any(Path(folder).glob(f"{module}.{kernel.py_func.__qualname__}-*.nbi"))


def check_kernel_cache(package: Path = PACKAGE) -> bool:
    """Remove ringlight's compiled kernels from numba's cache when the sources they can reach
    changed since they were stamped (module docstring). Returns True when entries were removed
    (or there was no stamp: then no entry can be trusted). Never raises: a cache it cannot read or
    write is left to numba."""
    sources = package_sources(package)
    folders = cache_folders(package, sources)
    stamp_path = folders.get(package)
    if stamp_path is None:  # no source files to stamp (a frozen or zipped application)
        return False
    try:
        stamp = json.loads((stamp_path / STAMP_NAME).read_text())
        kept_stats, kept_fingerprint = str(stamp["stats"]), str(stamp["sources"])
    except (OSError, ValueError, KeyError, TypeError):
        kept_stats = kept_fingerprint = None
    stats = _stats_digest(package, sources)
    if stats == kept_stats:
        return False
    try:
        texts = _read(sources)
    except OSError:  # a source removed or unreadable meanwhile: nothing is known, nothing done
        return False
    fingerprint = _fingerprint(package, _reachable(texts), texts)
    removed = fingerprint != kept_fingerprint
    if not removed or _remove_entries(folders, sources):
        _write_stamp(stamp_path, {"stats": stats, "sources": fingerprint})
    return removed


def cache_folders(package: Path = PACKAGE, sources: list[Path] | None = None) -> dict[Path, Path]:
    """Each source folder of ``package`` and the folder numba caches its modules' kernels in, as
    numba's locators choose it (module docstring). ``sources``: :func:`package_sources` when the
    caller has them."""
    folders = sorted({path.parent for path in (package_sources(package) if sources is None else sources)})
    base = os.environ.get("NUMBA_CACHE_DIR", "")
    if not base:
        in_tree = package / "__pycache__"
        if os.access(in_tree if in_tree.is_dir() else package, os.W_OK):
            return {folder: folder / "__pycache__" for folder in folders}
        from numba.misc.appdirs import AppDirs  # numba's UserWideCacheLocator's folder

        base = AppDirs(appname="numba", appauthor=False).user_cache_dir
    # numba's _CacheLocator.get_suitable_cache_subpath: the folder's name and its path's SHA-1.
    return {folder: Path(base) / f"{folder.name}_{hashlib.sha1(str(folder).encode()).hexdigest()}"
            for folder in folders}


def package_sources(package: Path) -> list[Path]:
    """Every ``.py`` file of ``package`` and its subpackages, sorted (numba's and Python's
    ``__pycache__`` folders, which hold hundreds of files, not walked)."""
    found = []
    for folder, subfolders, files in os.walk(package):
        subfolders[:] = [name for name in subfolders if name != "__pycache__"]
        found.extend(Path(folder, name) for name in files if name.endswith(".py"))
    return sorted(found)


def kernel_sources(sources: list[Path]) -> list[Path]:
    """The modules among ``sources`` (a package's, :func:`package_sources`) a compiled kernel can
    reach: those that use numba and, transitively, every module of the package they import (what a
    kernel can call, inline or read a constant from), sorted."""
    return _reachable(_read(sources))


def _read(sources: list[Path]) -> dict[Path, str]:
    return {path: path.read_text(encoding="utf-8", errors="replace") for path in sources}


def _reachable(texts: dict[Path, str]) -> list[Path]:
    """:func:`kernel_sources` of the sources' ``texts``."""
    # This module imports numba only to find its per-user folder: it compiles nothing.
    reached = {path for path, text in texts.items() if _USES_NUMBA.search(text) and path != _THIS_FILE}
    waiting = list(reached)
    while waiting:
        for imported in _imports(waiting.pop(), texts):
            if imported not in reached:
                reached.add(imported)
                waiting.append(imported)
    return sorted(reached)


def _imports(path: Path, texts: dict[Path, str]) -> set[Path]:
    """The modules of the package that ``path``'s relative imports name: ``from .a.b import c``
    is ``a/b.py`` or ``a/b/__init__.py``, and ``a/b/c.py`` where ``c`` is a module."""
    found = set()
    for dots, module, names in _IMPORT.findall(texts[path]):
        base = path.parent
        for _ in range(len(dots) - 1):
            base = base.parent
        target = base.joinpath(*module.split(".")) if module else base
        candidates = [target / "__init__.py"] + [target / f"{name}.py" for name in re.findall(r"\w+", names)]
        if module:
            candidates.append(target.with_suffix(".py"))
        found.update(candidate for candidate in candidates if candidate in texts)
    return found


def _stats_digest(package: Path, sources: list[Path]) -> str:
    """SHA-256 of every source's relative path, size and modification time (ns)."""
    digest = hashlib.sha256()
    for path in sources:
        try:
            status = path.stat()
        except OSError:
            continue
        digest.update(f"{path.relative_to(package)}\0{status.st_size}\0{status.st_mtime_ns}\n".encode())
    return digest.hexdigest()


def _fingerprint(package: Path, sources: list[Path], texts: dict[Path, str]) -> str:
    """SHA-256 of the relative paths and ``texts`` of ``sources``."""
    digest = hashlib.sha256()
    for path in sources:
        digest.update(f"{path.relative_to(package)}\0{texts[path]}".encode(errors="replace"))
    return digest.hexdigest()


def _remove_entries(folders: dict[Path, Path], sources: list[Path]) -> bool:
    """Delete numba's index and data files of every module in ``sources`` (``<module>.<function>-
    <line>.py<version>.nbi`` and ``.nbc``) from its folder's cache, each folder listed once; other
    files are left alone. False when one could not be deleted (the stamp is then not renewed: the
    next process tries again)."""
    modules: dict[Path, set[str]] = {}
    for path in sources:
        modules.setdefault(folders[path.parent], set()).add(path.stem)
    for cache, stems in modules.items():
        try:
            entries = [entry for entry in cache.iterdir()
                       if entry.suffix in (".nbi", ".nbc") and entry.name.split(".", 1)[0] in stems]
        except FileNotFoundError:  # nothing cached for this folder yet
            continue
        except OSError:
            return False
        for entry in entries:
            try:
                entry.unlink()
            except FileNotFoundError:  # another process removed it first
                pass
            except OSError:
                return False
    return True


def _write_stamp(folder: Path, stamp: dict[str, str]) -> None:
    """The stamp written atomically (:func:`.atomic.atomic_file`); a folder that cannot be written
    is left without one."""
    try:
        with atomic_file(folder / STAMP_NAME, overwrite=True) as temporary:
            temporary.write_text(json.dumps(stamp))
    except (OSError, RinglightError):
        pass
