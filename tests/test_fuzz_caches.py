"""The user caches' .npz files (``simulate --noise`` checkpoints, the inversion's white databases)
under truncation, flipped bits, a FIFO in their place, another run's file and hand-made files with
wrong contents (issue 40, cases 5 and 8): a checkpoint is either read back exactly as saved or
refused in one line naming it; a white database is either read back exactly or run again (the
same records, as the run is seeded) and replaced; never a traceback, a hang or an allocation
larger than the file. Hypothesis draws the byte cut or the bit flipped."""

from __future__ import annotations

import os
import tracemalloc
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ringlight.app.main import main
from ringlight.core.checked_arrays import digest
from ringlight.core.inversion.white_mc import DatabaseError, SlabOptics, database_path, white_database
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.progressive import (
    CheckpointError,
    checkpoint_path,
    fingerprint,
    load_checkpoint,
    simulate_until,
)

FUZZ = settings(max_examples=60, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])
SCENE = ("layers3", (6, 6))
OPTICS = SlabOptics(mus=(1.0, 2.0), g=0.0, n=1.4, depth=1.5, reach=3)
PHOTONS = 256


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private user cache holding one checkpoint and one white database, with their bytes."""
    folder = tmp_path_factory.mktemp("cache")
    previous = os.environ.get("RINGLIGHT_CACHE_DIR")
    os.environ["RINGLIGHT_CACHE_DIR"] = str(folder)
    try:
        scene = load_scene(SCENE[0], size=SCENE[1])
        simulate_until(scene, seconds=1e-9, batch=5)  # two batches, saved
        checkpoint = checkpoint_path(fingerprint(scene, scene.seed, 5, "reference"))
        white = white_database(OPTICS, PHOTONS)
        database = database_path(OPTICS, PHOTONS, 0)
        yield {"folder": folder, "scene": scene, "checkpoint": checkpoint, "bytes": checkpoint.read_bytes(),
               "sums": load_checkpoint(checkpoint, scene), "white": white, "database": database,
               "database bytes": database.read_bytes()}
    finally:
        if previous is None:
            del os.environ["RINGLIGHT_CACHE_DIR"]
        else:
            os.environ["RINGLIGHT_CACHE_DIR"] = previous


@pytest.fixture(autouse=True)
def module_cache(cache, monkeypatch):
    """The module's cache for every test (conftest gives each test a fresh one)."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(cache["folder"]))


def damaged(data: bytes, cut: int | None, flip: int | None) -> bytes:
    if cut is not None:
        return data[:cut % max(len(data), 1)]
    flipped = bytearray(data)
    flipped[(flip // 8) % len(data)] ^= 1 << (flip % 8)
    return bytes(flipped)


MUTATIONS = st.one_of(st.tuples(st.integers(0, 2**40), st.none()), st.tuples(st.none(), st.integers(0, 2**40)))


def peak_bytes(function):
    tracemalloc.start()
    try:
        function()
    except (CheckpointError, DatabaseError):
        pass
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak


@FUZZ
@given(mutation=MUTATIONS)
def test_a_damaged_checkpoint_is_read_exactly_or_refused_in_one_line(cache, mutation):
    path = cache["checkpoint"]
    path.write_bytes(damaged(cache["bytes"], *mutation))
    try:
        sums = load_checkpoint(path, cache["scene"])
    except CheckpointError as error:
        assert str(error).startswith(f"{path}: unreadable simulation checkpoint (") and "\n" not in str(error)
    else:
        expected = cache["sums"]
        for name in ("windows", "truth", "transients", "squares", "batches", "seconds"):
            np.testing.assert_array_equal(getattr(sums, name), getattr(expected, name))
    # Memory is bounded by the file: a flipped header once asked numpy for 33 GiB.
    assert peak_bytes(lambda: load_checkpoint(path, cache["scene"])) < 4 * len(cache["bytes"]) + 2**20


def saved_by_hand(path, **arrays):
    """What the issue's hand-made checkpoints were: np.savez of plausible sums, no check."""
    with open(path, "wb") as handle:
        np.savez(handle, **arrays)


@pytest.mark.parametrize("change", ["batches 0", "batches -1", "batches 2^62", "NaN", "scaled", "another run's"])
def test_a_checkpoint_with_wrong_contents_is_refused(cache, change):
    """Five valid hand-made checkpoints changed the result with no message (case 5): the file now
    carries its run's key and a digest, and the sums must be possible (batch count, finite,
    squares at least the squared sums over the batches)."""
    path, sums = cache["checkpoint"], cache["sums"]
    arrays = {"windows": sums.windows, "truth": sums.truth, "transients": sums.transients, "squares": sums.squares,
              "batches": np.int64(sums.batches), "seconds": np.float64(sums.seconds)}
    if change.startswith("batches"):
        arrays["batches"] = np.int64({"batches 0": 0, "batches -1": -1, "batches 2^62": 2**62}[change])
    elif change == "NaN":
        arrays["windows"] = np.where(sums.windows == sums.windows.max(), np.nan, sums.windows)
    elif change == "scaled":
        arrays = {**arrays, "transients": sums.transients * 3, "windows": sums.windows * 3}
    saved_by_hand(path, **arrays)
    with pytest.raises(CheckpointError, match=r"it has no check and no key \(written by an older ringlight"):
        load_checkpoint(path, cache["scene"])
    # Even with the key and a digest recomputed (a forger's file), impossible sums are refused.
    key = "another run" if change == "another run's" else path.stem
    saved_by_hand(path, **arrays, key=np.array(key), check=np.array(digest(key, arrays)))
    with pytest.raises(CheckpointError) as refused:
        load_checkpoint(path, cache["scene"])
    assert str(refused.value).startswith(f"{path}: unreadable simulation checkpoint (") and "\n" not in str(refused.value)


def test_a_fifo_in_place_of_a_checkpoint_or_a_database_is_one_line_at_once(cache, tmp_path):
    """Case 8: reading blocked for good."""
    for path in (cache["checkpoint"], cache["database"]):
        path.unlink()
        os.mkfifo(path)
    try:
        with pytest.raises(CheckpointError, match=r"unreadable simulation checkpoint \(not a regular file\)"):
            load_checkpoint(cache["checkpoint"], cache["scene"])
        with pytest.raises(DatabaseError, match=r"not a white Monte Carlo database \(not a regular file\)"):
            white_database(OPTICS, PHOTONS)
    finally:
        cache["checkpoint"].unlink()
        cache["checkpoint"].write_bytes(cache["bytes"])
        cache["database"].unlink()
        cache["database"].write_bytes(cache["database bytes"])


@FUZZ
@given(mutation=MUTATIONS)
def test_a_damaged_white_database_is_read_exactly_or_run_again(cache, mutation):
    path, white = cache["database"], cache["white"]
    path.write_bytes(damaged(cache["database bytes"], *mutation))
    database = white_database(OPTICS, PHOTONS)  # a damaged file is run again: the same seeded records
    for name in ("pixel", "value", "lengths", "photon"):
        np.testing.assert_array_equal(getattr(database, name), getattr(white, name))
    assert database.photons == white.photons
    with zipfile.ZipFile(path) as archive:  # and the file replaced by a whole one
        assert {"key.npy", "check.npy", "pixel.npy"} <= set(archive.namelist())


def test_the_command_line_names_a_truncated_checkpoint_in_one_line(cache, capsys, tmp_path):
    path = cache["checkpoint"]
    path.write_bytes(cache["bytes"][:1000])
    try:
        status = main(["simulate", SCENE[0], "--size", "6x6", "--noise", "0.5", "--photons", "5",
                       "--out", str(tmp_path / "out")])
    finally:
        path.write_bytes(cache["bytes"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "Traceback" not in err[0]
    assert err[0].startswith(f"ringlight: error: {path}: unreadable simulation checkpoint (")
    assert err[0].endswith("; delete it to start afresh") and not (tmp_path / "out").exists()
