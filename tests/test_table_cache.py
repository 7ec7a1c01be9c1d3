"""The optics look-up tables kept in the user cache (ringlight.core.optics.table_cache): read back
bitwise as built, built again when damaged, foreign or of another key; the reference is
build_table on the same white run, run in the test."""

import os

import numpy as np
import pytest
from ringlight.core.checked_arrays import save_checked
from ringlight.core.optics import radial, table, table_cache
from ringlight.core.optics.table import build_table  # the reference, bound before `builds` counts

N, G, SEED = 1.3, 0.2, 4
PHOTONS = table.PHOTON_RANGE[0]  # the fewest table_for takes (these tests used 320 before it checked)
RADII = np.arange(3.0)


@pytest.fixture(autouse=True)
def small_tables(monkeypatch):
    """No tables in memory, and a coarse grid (built in milliseconds; the grid is part of the key)."""
    monkeypatch.setattr(table, "_TABLES", {})
    monkeypatch.setattr(table, "SCATTERING_POINTS", 9)
    monkeypatch.setattr(table, "ALBEDO_POINTS", 7)


@pytest.fixture
def builds(monkeypatch):
    """The rings of every table built (not read back) in the test."""
    calls = []

    def counted(run, radii, *args, **kwargs):
        calls.append(np.asarray(radii).tolist())
        return build_table(run, radii, *args, **kwargs)

    monkeypatch.setattr(table, "build_table", counted)
    return calls


def assert_same_table(kept, built):
    """Every array bitwise and every number equal (the run too: the same white run's arrays)."""
    for name in ("radii", "log_profile"):
        assert getattr(kept, name).dtype == getattr(built, name).dtype
        assert getattr(kept, name).tobytes() == getattr(built, name).tobytes(), name
    for name in ("thickness", "antialias", "n", "g", "u0", "du", "v0", "dv", "photons"):
        assert getattr(kept, name) == getattr(built, name), name
    for name in ("weight", "rho", "path"):
        assert getattr(kept.run, name).tobytes() == getattr(built.run, name).tobytes(), name


def kept_path(radii=RADII, n=N, g=G, thickness=1.0, antialias=False, cut=None):
    run = radial.radial_run(n, g, PHOTONS, SEED)
    return table_cache.table_path(table_cache.table_key(run, np.asarray(radii, np.float64), thickness, antialias,
                                                        PHOTONS, SEED, cut))


def test_a_table_read_back_in_another_process_equals_the_built_one_bitwise(builds):
    first = table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    assert builds == [RADII.tolist()] and kept_path().is_file()
    table._TABLES.clear()  # as a new process finds it
    again = table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    assert builds == [RADII.tolist()]  # read, not built
    assert_same_table(again, first)
    assert_same_table(again, build_table(radial.radial_run(N, G, PHOTONS, SEED), RADII))


@pytest.mark.parametrize("damage", ["truncated", "flipped byte", "another key's table", "empty"])
def test_a_damaged_or_foreign_table_is_built_again_and_replaced(builds, damage):
    table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    path = kept_path()
    data = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(data[:-100])
    elif damage == "flipped byte":
        position = data.index(b"log_profile.npy") + 200  # inside the table's values
        path.write_bytes(data[:position] + bytes([data[position] ^ 0x10]) + data[position + 1:])
    elif damage == "another key's table":
        table.table_for(N, G, np.arange(4.0), photons=PHOTONS, seed=SEED)
        path.write_bytes(kept_path(np.arange(4.0)).read_bytes())
    else:
        path.write_bytes(b"")
    table._TABLES.clear()
    rebuilt = table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    assert builds.count(RADII.tolist()) == 2
    assert_same_table(rebuilt, build_table(radial.radial_run(N, G, PHOTONS, SEED), RADII))
    table._TABLES.clear()
    table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)  # the replacement is read back
    assert builds.count(RADII.tolist()) == 2


def test_another_key_does_not_hit(builds):
    table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    cut = np.zeros((3, 5, 5))
    cut[:, 2, 2:] = 1.0  # each "ring" a row of offsets (0, 0), (0, 1), (0, 2)
    others = [dict(n=N, g=G, radii=np.arange(4.0)), dict(n=N, g=G, radii=RADII + 0.5),
              dict(n=1.4, g=G, radii=RADII), dict(n=N, g=0.0, radii=RADII),
              dict(n=N, g=G, radii=RADII, thickness=1.5), dict(n=N, g=G, radii=RADII, antialias=True),
              dict(n=N, g=G, radii=RADII, ring_weights=cut), dict(n=N, g=G, radii=RADII, ring_weights=cut * 2.0)]
    for number, other in enumerate(others, start=2):
        table._TABLES.clear()
        kept = table.table_for(photons=PHOTONS, seed=SEED, **other)
        assert len(builds) == number, other
        reference = build_table(radial.radial_run(other["n"], other["g"], PHOTONS, SEED), other["radii"],
                                      other.get("thickness", 1.0), other.get("antialias", False),
                                      other.get("ring_weights"))
        assert_same_table(kept, reference)


def test_a_new_white_run_in_the_runs_place_is_not_served_the_old_runs_table(builds):
    # A CUDA run of as many photons takes the CPU run's file: another sample, so another table.
    table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    other = radial.run_radial(N, G, PHOTONS, seed=SEED + 1)
    path = radial.radial_path(N, G, PHOTONS, SEED)
    save_checked(path, path.stem, {"photons": np.int64(other.photons), "weight": other.weight, "rho": other.rho,
                                   "path": other.path, "seconds": np.float64(other.seconds)})
    table._TABLES.clear()
    kept = table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    assert len(builds) == 2
    assert_same_table(kept, build_table(other, RADII))


def test_a_kept_table_counts_toward_the_white_cache_limit(builds, monkeypatch):
    table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    first = kept_path()
    os.utime(first, (1, 1))  # used long ago
    run = radial.radial_path(N, G, PHOTONS, SEED)
    # Room for the run and two tables of 3 rings: a table of 4 rings (4/3 the size) is written,
    # so the least recently used file, the first table, goes.
    monkeypatch.setenv("RINGLIGHT_WHITE_CACHE", str(run.stat().st_size + 2 * first.stat().st_size))
    table.table_for(N, G, np.arange(4.0), photons=PHOTONS, seed=SEED)
    assert kept_path(np.arange(4.0)).is_file() and run.is_file() and not first.exists()


def test_a_fifo_in_place_of_a_table_is_one_line_naming_it(builds):
    path = kept_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    with pytest.raises(radial.TableError, match="not a look-up table of ringlight's") as error:
        table.table_for(N, G, RADII, photons=PHOTONS, seed=SEED)
    assert str(path) in str(error.value) and "\n" not in str(error.value)
