"""numba's cache kept true to the sources (:mod:`ringlight.core.kernel_cache`).

A small package of three modules stands in for ringlight's: ``a.f`` is a cached kernel that calls
``b.g``, inlines ``b.h`` and reads ``constants.SCALE`` through ``b``. Its results, computed by hand
from the sources, are the reference: numba alone keeps ``f``'s old code after ``b`` or
``constants`` change (the hazard, shown first, so that the check's passing is not vacuous), and
with the check first ``f`` follows every change, while an unchanged package loads from the cache.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

from ringlight.core import kernel_cache
from ringlight.core.kernel_cache import STAMP_NAME, cache_folders, check_kernel_cache, kernel_sources, package_sources
from ringlight.core.rings.stacks import _ring_sums

A = """import numba
from .b import g, h

@numba.njit(cache=True)
def f(x):
    return g(x) + h(x)
"""
B = """import numba
from .constants import SCALE

@numba.njit(cache=True)
def g(x):
    return x * SCALE

@numba.njit(cache=True, inline="always")
def h(x):
    return x + {added}
"""
RUN = """import sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
if sys.argv[2] == "checked":
    from ringlight.core.kernel_cache import check_kernel_cache

    check_kernel_cache(Path(sys.argv[1]) / "pkg")
from pkg.a import f
print(f(1.0), sum(f.stats.cache_hits.values()))
"""


def _package(root: Path, scale: float = 2.0, added: float = 1.0) -> None:
    package = root / "pkg"
    package.mkdir(exist_ok=True)
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text(A)
    (package / "b.py").write_text(B.format(added=added))
    (package / "constants.py").write_text(f"SCALE = {scale}\n")
    (package / "unrelated.py").write_text("NOTE = 'no kernel reaches this module'\n")


def _f(root: Path, checked: bool, env: dict) -> tuple[float, int]:
    """f(1) and the cache hits of a fresh process: 1.0 * SCALE + 1.0 + added."""
    result = subprocess.run([sys.executable, "-c", RUN, str(root), "checked" if checked else "plain"],
                            capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 0, result.stderr
    value, hits = result.stdout.split()
    return float(value), int(hits)


def _environment(numba_cache_dir: Path | None) -> dict:
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    if numba_cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = str(numba_cache_dir)
    return env


def test_a_kernel_follows_every_change_to_what_it_calls_inlines_or_reads(tmp_path):
    """numba's in-tree cache (the package's __pycache__), as README's editable install has it."""
    env = _environment(None)
    _package(tmp_path)
    assert _f(tmp_path, True, env) == (4.0, 0)  # compiled: 1 * 2 + 1 + 1
    assert _f(tmp_path, True, env) == (4.0, 1)  # unchanged: loaded from the cache
    _package(tmp_path, scale=3.0)
    # The hazard: numba alone runs f's old code (4, not 5) after a constant it reads changed.
    assert _f(tmp_path, False, env) == (4.0, 1), "numba now invalidates across files: kernel_cache may go"
    assert _f(tmp_path, True, env) == (5.0, 0)  # 1 * 3 + 1 + 1, compiled afresh
    _package(tmp_path, scale=3.0, added=10.0)  # the inlined function
    assert _f(tmp_path, True, env) == (14.0, 0)
    (tmp_path / "pkg" / "unrelated.py").write_text("NOTE = 'edited'\n")  # no kernel reaches it: the cache stays
    assert _f(tmp_path, True, env) == (14.0, 1)


def test_a_kernel_cached_under_numba_cache_dir_follows_a_change_too(tmp_path):
    env = _environment(tmp_path / "numba-cache")
    _package(tmp_path)
    assert _f(tmp_path, True, env) == (4.0, 0)
    _package(tmp_path, scale=3.0, added=10.0)
    assert _f(tmp_path, True, env) == (14.0, 0)
    assert _f(tmp_path, True, env) == (14.0, 1)
    assert (tmp_path / "numba-cache").is_dir() and not (tmp_path / "pkg" / "__pycache__" / STAMP_NAME).exists()


def test_the_sources_a_kernel_reaches_are_the_numba_modules_and_what_they_import(tmp_path):
    _package(tmp_path)
    package = tmp_path / "pkg"
    (package / "sub").mkdir()
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "deep.py").write_text("from ..unrelated import NOTE\nfrom . import (\n    sibling,\n)\n")
    (package / "sub" / "sibling.py").write_text("")
    (package / "b.py").write_text(B.format(added=1.0) + "from .sub.deep import NOTE as DEEP\n")
    sources = package_sources(package)
    assert sources == sorted(package.rglob("*.py"))
    reached = [path.relative_to(package).as_posix() for path in kernel_sources(sources)]
    # a and b use numba; b imports constants and sub.deep; deep imports unrelated and, from its own
    # package, sibling (and so sub's __init__). No module imports pkg/__init__.py.
    assert reached == ["a.py", "b.py", "constants.py", "sub/__init__.py", "sub/deep.py", "sub/sibling.py",
                       "unrelated.py"]


def _entries(folder: Path) -> list[str]:
    return sorted(path.name for path in folder.iterdir())


def test_only_the_changed_packages_numba_entries_are_removed_and_a_bad_stamp_trusts_nothing(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    _package(tmp_path)
    package = tmp_path / "pkg"
    cache = package / "__pycache__"
    cache.mkdir()
    names = ["a.f-4.py311.nbi", "a.f-4.py311.1.nbc", "b.g-4.py311.nbi", "a.cpython-311.pyc", "notes.txt"]
    for name in names:
        (cache / name).write_text("x")
    assert cache_folders(package)[package] == cache
    assert check_kernel_cache(package)  # no stamp: no entry can be trusted
    assert _entries(cache) == ["a.cpython-311.pyc", "notes.txt", STAMP_NAME]
    stamp = json.loads((cache / STAMP_NAME).read_text())
    for name in names[:3]:
        (cache / name).write_text("x")
    assert not check_kernel_cache(package)  # nothing changed
    (package / "unrelated.py").write_text("NOTE = 'edited'\n")
    assert not check_kernel_cache(package)  # changed, but no kernel reaches it: the stamp's times renewed
    renewed = json.loads((cache / STAMP_NAME).read_text())
    assert renewed["sources"] == stamp["sources"] and renewed["stats"] != stamp["stats"]
    assert len(_entries(cache)) == 6
    (cache / STAMP_NAME).write_text("{not json")
    assert check_kernel_cache(package)
    assert _entries(cache) == ["a.cpython-311.pyc", "notes.txt", STAMP_NAME]


def test_the_folders_are_those_numbas_own_locators_name(tmp_path, monkeypatch):
    """Where numba's locators put a kernel of ringlight's: under NUMBA_CACHE_DIR, in the tree, and
    in the per-user folder when the tree cannot be written."""
    from numba.core.caching import InTreeCacheLocator, UserProvidedCacheLocator, UserWideCacheLocator

    package = Path(kernel_cache.__file__).parent
    kernel = _ring_sums.py_func
    module = Path(kernel.__code__.co_filename)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-cache"))
    monkeypatch.setattr("numba.core.config.CACHE_DIR", str(tmp_path / "numba-cache"))  # as numba read it
    locator = UserProvidedCacheLocator(kernel, str(module))
    assert cache_folders(package)[module.parent] == Path(locator.get_cache_path())
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert cache_folders(package)[module.parent] == Path(InTreeCacheLocator(kernel, str(module)).get_cache_path())
    monkeypatch.setattr(kernel_cache.os, "access", lambda path, mode: False)  # a tree ringlight cannot write
    assert cache_folders(package)[module.parent] == Path(UserWideCacheLocator(kernel, str(module)).get_cache_path())


def test_a_package_without_source_files_is_left_alone(tmp_path):
    """A frozen or zipped application has no sources to stamp: nothing is removed or written."""
    (tmp_path / "frozen").mkdir()
    assert not check_kernel_cache(tmp_path / "frozen")
    assert not check_kernel_cache(tmp_path / "absent")
    assert list(tmp_path.rglob("*")) == [tmp_path / "frozen"]


def test_ringlights_own_stamp_is_current_after_import():
    """``import ringlight.core`` checked the cache: the stamp lies where numba keeps the kernels."""
    folders = cache_folders()
    package = Path(kernel_cache.__file__).parent
    assert not check_kernel_cache()
    assert (folders[package] / STAMP_NAME).is_file()


IS_CACHED = """
import sys

sys.path.insert(0, sys.argv[1])
from numba import njit

from ringlight.core.kernel_cache import is_cached
from tiny import twice

before = is_cached(twice)
twice(2.0)
print(before, is_cached(twice), is_cached(njit(lambda x: x)))
"""


def test_is_cached_says_whether_numbas_cache_holds_a_kernel_before_and_after_its_first_call(tmp_path):
    """The first-run notes (the window's, the maps' fits) ask it; a kernel numba does not cache is
    taken as cached (nothing would compile ahead)."""
    (tmp_path / "tiny.py").write_text("from numba import njit\n\n\n@njit(cache=True)\n"
                                      "def twice(x):\n    return 2 * x\n")
    result = subprocess.run([sys.executable, "-c", IS_CACHED, str(tmp_path)], capture_output=True, text=True,
                            timeout=300, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "True", "True"]
