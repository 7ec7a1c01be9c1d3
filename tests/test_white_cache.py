"""The white Monte Carlo databases' cache: least recently used dropped down to a limit."""

import os

import numpy as np
import pytest
import ringlight.core.inversion.white_mc as white_mc
from ringlight.core.errors import RinglightError
from ringlight.core.inversion import white_cache
from ringlight.core.inversion.white_mc import SlabOptics, database_path, white_database


def database_file(folder, index: int, size: int, age: int):
    """A file named as a database (24 hex digits), ``size`` bytes, used ``age`` hours ago."""
    path = folder / f"{index:024x}.npz"
    path.write_bytes(b"x" * size)
    when = 1_700_000_000 - 3600 * age
    os.utime(path, (when, when))
    return path


def test_the_least_recently_used_go_first_and_nothing_but_databases_is_touched(tmp_path):
    folder = tmp_path / "white"
    folder.mkdir()
    files = [database_file(folder, index, 100, age=10 - index) for index in range(5)]  # files[0] oldest
    other = folder / "notes.npz"
    other.write_bytes(b"y" * 1000)  # not a database's name: neither counted nor deleted
    outside = tmp_path / "mine.npz"
    outside.write_bytes(b"z" * 1000)
    (folder / f"{99:024x}.npz").symlink_to(outside)  # a link named as a database
    (folder / f"{98:024x}.npz").mkdir()  # a folder named as one
    # 500 bytes of databases, 250 allowed: the three used longest ago go, except the one kept.
    deleted = white_cache.evict(folder, keep=files[0], limit=250)
    assert deleted == [files[1], files[2], files[3]]
    assert sorted(path.name for path in folder.iterdir()) == sorted(
        [files[0].name, files[4].name, "notes.npz", f"{99:024x}.npz", f"{98:024x}.npz"])
    assert outside.read_bytes() == b"z" * 1000 and other.stat().st_size == 1000
    assert white_cache.evict(folder, keep=files[4], limit=250) == []  # 200 bytes left: within the limit


def test_the_limit_comes_from_the_environment(monkeypatch):
    monkeypatch.delenv("RINGLIGHT_WHITE_CACHE", raising=False)
    assert white_cache.cache_limit() == white_cache.CACHE_BYTES == 4 * 2**30
    monkeypatch.setenv("RINGLIGHT_WHITE_CACHE", "1.5G")
    assert white_cache.cache_limit() == int(1.5 * 2**30)
    monkeypatch.setenv("RINGLIGHT_WHITE_CACHE", "lots")
    with pytest.raises(RinglightError, match=r"\$RINGLIGHT_WHITE_CACHE: 'lots' is not a size"):
        white_cache.cache_limit()


def test_a_database_loaded_again_outlives_one_made_after_it(tmp_path, monkeypatch):
    """Three small white runs with room for two: the one not used since it was made goes."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    optics = [SlabOptics((1.0,) * 3, g, 1.3, 8.0, 4) for g in (0.0, 0.3, 0.6)]
    first = white_database(optics[0], 2000)
    white_database(optics[1], 2000)
    paths = [database_path(o, 2000, 0) for o in optics[:2]]
    for age, path in zip((2, 1), paths):  # made two and one hours ago
        when = path.stat().st_mtime - 3600 * age
        os.utime(path, (when, when))
    again = white_database(optics[0], 2000)  # loaded: used now
    np.testing.assert_array_equal(again.value, first.value)
    sizes = [path.stat().st_size for path in paths]
    # Room for the first and a third like the second (each run's size varies with its photons).
    monkeypatch.setenv("RINGLIGHT_WHITE_CACHE", str(sizes[0] + sizes[1] + sizes[1] // 2))
    white_database(optics[2], 2000)
    assert paths[0].exists() and not paths[1].exists() and database_path(optics[2], 2000, 0).exists()


def test_a_bad_limit_is_told_before_the_run(tmp_path, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("RINGLIGHT_WHITE_CACHE", "lots")
    runs = []
    monkeypatch.setattr(white_mc, "run_white", lambda *args: runs.append(args))
    with pytest.raises(RinglightError, match="RINGLIGHT_WHITE_CACHE"):
        white_database(SlabOptics((1.0,) * 3, 0.0, 1.3, 8.0, 4), 2000)
    assert runs == []


def test_a_database_dropped_by_another_process_while_loading_is_run_again(tmp_path, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    optics = SlabOptics((1.0,) * 3, 0.0, 1.3, 8.0, 4)
    first = white_database(optics, 2000)
    path = database_path(optics, 2000, 0)
    load = np.load

    def evicted_meanwhile(file, **options):  # another process's eviction wins the race
        path.unlink()
        return load(file, **options)

    monkeypatch.setattr(white_mc.np, "load", evicted_meanwhile)
    again = white_database(optics, 2000)
    np.testing.assert_array_equal(again.value, first.value)  # the same seed: the same records
    assert path.exists()  # and cached again


def test_a_stored_database_is_read_back_and_an_unwritable_place_is_skipped(tmp_path):
    from ringlight.core.checked_arrays import load_checked

    folder = tmp_path / "white"
    folder.mkdir()
    old = database_file(folder, 1, 300, age=5)
    path = folder / f"{2:024x}.npz"
    white_cache.store(path, "key", {"values": np.arange(4.0)}, limit=250)
    assert load_checked(path, "key", ("values",))["values"].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert not old.exists()  # over the limit: the one used longest ago went
    # A folder that cannot hold the file (a regular file in its place): skipped, nothing raised or evicted.
    kept = database_file(folder, 3, 300, age=5)
    blocked = tmp_path / "blocked"
    blocked.write_bytes(b"")
    white_cache.store(blocked / f"{4:024x}.npz", "key", {"values": np.arange(4.0)}, limit=0)
    assert kept.exists() and blocked.read_bytes() == b""


def test_optics_given_as_integers_are_the_same_optics_as_floats(tmp_path, monkeypatch):
    """A depth of 8 and of 8.0 (g 0 and 0.0, ...) are one slab: one cache file, and one run read
    back from it (json wrote "8" and "8.0", two keys, and numba compiled the walk once for each)."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    whole = SlabOptics((1, 1, 1), 0, 1, 8, 4.0)
    floats = SlabOptics((1.0, 1.0, 1.0), 0.0, 1.0, 8.0, 4)
    assert whole.key(500, 0) == floats.key(500, 0) and database_path(whole, 500, 0) == database_path(floats, 500, 0)
    types = [type(v) for v in (whole.g, whole.n, whole.depth, whole.reach, *whole.mus)]
    assert types == [float] * 3 + [int] + [float] * 3
    first = white_database(whole, 500)
    again = white_database(floats, 500)
    assert again.seconds == first.seconds  # read back from the file the first wrote, not run again
    np.testing.assert_array_equal(again.lengths, first.lengths)
