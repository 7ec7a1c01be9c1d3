"""The explorer's stacks and noise saved in the user cache: read back bit for bit, keyed by all
they depend on, never shown when damaged, and trimmed to their bound least recently used first."""

import dataclasses
import json
import shutil
import subprocess
import threading
import os
import time

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from reference import brute_ring_image, random_impulses, write_dataset
import ringlight.core.staging_locks as staging_locks
from ringlight.core import RinglightError, open_dataset
from ringlight.core.rings import stack_cache
from ringlight.core.rings.coverage import ring_coverage
from ringlight.core.rings.noise import stack_noise
from ringlight.core.rings.stack_request import StackRequest, compute_stacks

HEIGHT, WIDTH = 9, 8
REQUEST = StackRequest(start=0.0, stop=3.0, step=1.0, dr=1.0)


@pytest.fixture
def impulses():
    return random_impulses(np.random.default_rng(3), HEIGHT, WIDTH, support=10)


@pytest.fixture
def folder(tmp_path, impulses):
    write_dataset(tmp_path / "ds", HEIGHT, WIDTH, impulses)
    return tmp_path / "ds"


class Computations:
    """Counts the stacks, noise and coverage computed (rather than read from the cache)."""

    def __init__(self, monkeypatch):
        self.stacks = self.noise = self.coverage = 0

        def stacks(*args, **kwargs):
            self.stacks += 1
            return compute_stacks(*args, **kwargs)

        def noise(*args, **kwargs):
            self.noise += 1
            return stack_noise(*args, **kwargs)

        def coverage(*args, **kwargs):
            self.coverage += 1
            return ring_coverage(*args, **kwargs)

        monkeypatch.setattr(stack_cache, "compute_stacks", stacks)
        monkeypatch.setattr(stack_cache, "stack_noise", noise)
        monkeypatch.setattr(stack_cache, "ring_coverage", coverage)


def assert_same_pair(pair, expected):
    for kind in ("ring", "transient"):
        got, want = getattr(pair, kind), getattr(expected, kind)
        for name in ("radii", "images", "counts", "outer_counts"):
            if getattr(want, name) is None:
                assert getattr(got, name) is None
            else:
                assert_array_equal(getattr(got, name), getattr(want, name))
        assert (got.kind, got.step, got.thickness, got.antialias, got.colorspace) == \
            (want.kind, want.step, want.thickness, want.antialias, want.colorspace)


def assert_same_noise(noise, expected):
    for name in ("radii", "ring", "transient", "ring_luminance", "transient_luminance", "luminance_weights"):
        assert_array_equal(getattr(noise, name), getattr(expected, name))
    assert noise.step == expected.step


def entry_folders():
    root = stack_cache.cache_folder()
    return sorted(name for name in os.listdir(root) if not name.startswith(".")) if root.exists() else []


def test_a_reopen_reads_the_saved_stacks_noise_and_coverage_bit_for_bit(folder, impulses, monkeypatch):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    first, first_noise = stack_cache.cached_stacks(dataset, REQUEST), stack_cache.cached_noise(dataset, REQUEST)
    first_coverage = stack_cache.cached_coverage(dataset, REQUEST)
    assert (computed.stacks, computed.noise, computed.coverage) == (1, 1, 1)
    assert len(entry_folders()) == 3

    reopened = open_dataset(folder, radius=6)
    pair = stack_cache.cached_stacks(reopened, REQUEST)
    noise = stack_cache.cached_noise(reopened, REQUEST)
    coverage = stack_cache.cached_coverage(reopened, REQUEST)
    assert (computed.stacks, computed.noise, computed.coverage) == (1, 1, 1)
    expected = ring_coverage(reopened, REQUEST.radii(), REQUEST.thickness)
    for means in (coverage, first_coverage):
        assert_array_equal(means.radii, REQUEST.radii())
        assert_array_equal(means.member_fraction, expected.mean_member_fraction())
        assert_array_equal(means.nearest_offset, expected.mean_nearest_offset())
        assert_array_equal(means.poor(), expected.poor())
    assert_same_pair(pair, first)
    assert_same_noise(noise, first_noise)
    uncached = open_dataset(folder, radius=6, use_cache=False)
    assert_same_pair(pair, compute_stacks(uncached, REQUEST))
    assert_same_noise(noise, stack_noise(uncached, REQUEST.radii(), REQUEST.dr))
    # and the numbers are the definition's: T_2 = E_2 - E_3 by brute force
    brute = brute_ring_image(impulses, HEIGHT, WIDTH, 2.0) - brute_ring_image(impulses, HEIGHT, WIDTH, 3.0)
    np.testing.assert_allclose(pair.transient.images[2], brute, rtol=1e-5, atol=1e-6)


def test_anything_the_stacks_depend_on_gives_another_entry(folder, monkeypatch):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    stack_cache.cached_stacks(dataset, REQUEST)
    changes = [{"dr": 2.0}, {"thickness": 2.0}, {"antialias": True}, {"stop": 2.0}, {"start": 1.0}]
    for count, change in enumerate(changes, 2):
        request = REQUEST.with_changes(**change)
        assert_same_pair(stack_cache.cached_stacks(dataset, request), compute_stacks(dataset, request))
        assert computed.stacks == count
    assert computed.stacks == 6 and len(entry_folders()) == 6
    # another radius, and a frame touched since, make another store key
    stack_cache.cached_stacks(open_dataset(folder, radius=5.5), REQUEST)
    assert computed.stacks == 7
    later = time.time() + 10
    os.utime(folder / "frames/00004.exr", (later, later))
    stack_cache.cached_stacks(open_dataset(folder, radius=6), REQUEST)
    assert computed.stacks == 8
    # a dataset opened without the cache has no key: nothing is saved
    before = entry_folders()
    stack_cache.cached_stacks(open_dataset(folder, radius=6, use_cache=False), REQUEST)
    assert computed.stacks == 9 and entry_folders() == before


def _chunk(entry, array, index):
    """The chunk file of radius ``index`` of ``array`` (zarr's c/INDEX/0/0[/0])."""
    (path,) = (path for path in (entry / array / "c" / str(index)).rglob("*") if path.is_file())
    return path


DAMAGES = {
    "a byte flipped in an image": lambda entry: _flip(_chunk(entry, "transient_images", 1)),
    "two radii's images swapped": lambda entry: _swap(_chunk(entry, "ring_images", 0), _chunk(entry, "ring_images", 1)),
    "a radius's counts lost": lambda entry: _chunk(entry, "ring_counts", 2).unlink(),
    "an image's byte order edited, its size kept": lambda entry: _same_size_edit(entry / "ring_images" / "zarr.json",
                                                                                 b'"little"', b'"big"   '),
    "a stray file": lambda entry: (entry / "notes.txt").write_text("x"),
    "another key": lambda entry: _edit_meta(entry, lambda meta: meta.update(key="0" * 64)),
    "an array's shape edited and re-tabled": lambda entry: _edit_array(entry, "ring_images",
                                                                      lambda spec: spec["shape"].__setitem__(0, 3)),
    "meta.json not JSON": lambda entry: (entry / "meta.json").write_text("{"),
    # edits recorded in the table, as a hand that knows it would make them
    "a radius's images lost with their table line": lambda entry: _lose(entry, _chunk(entry, "transient_images", 2)),
    "an array's chunks edited to none and re-tabled": lambda entry: _edit_array(
        entry, "ring_images", lambda spec: spec["chunk_grid"]["configuration"].__setitem__("chunk_shape", [0, 9, 8, 3])),
    "an image's byte order edited and re-tabled": lambda entry: _edit_array(
        entry, "transient_images", lambda spec: spec["codecs"][0]["configuration"].__setitem__("endian", "big")),
    "an array's chunk keys edited and re-tabled": lambda entry: _edit_array(
        entry, "ring_counts", lambda spec: spec["chunk_key_encoding"]["configuration"].__setitem__("separator", ".")),
}


def _lose(entry, path):
    relative = path.relative_to(entry).as_posix()
    path.unlink()
    _edit_meta(entry, lambda meta: meta["table"].pop(relative))


def _flip(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))


def _same_size_edit(path, old, new):
    """An edit that keeps the file's size (only the table's SHA-256 can tell)."""
    data = path.read_bytes()
    assert data.count(old) == 1 and len(old) == len(new)
    path.write_bytes(data.replace(old, new))


def _swap(one, other):
    a, b = one.read_bytes(), other.read_bytes()
    one.write_bytes(b)
    other.write_bytes(a)


def _edit_meta(entry, change):
    meta = json.loads((entry / "meta.json").read_text())
    change(meta)
    (entry / "meta.json").write_text(json.dumps(meta))


def _edit_array(entry, name, change):
    """Edit an array's zarr.json and record the edit in the table, as a hand that knows the table
    would: the shape check must still refuse it."""
    import hashlib

    path = entry / name / "zarr.json"
    spec = json.loads(path.read_text())
    change(spec)
    path.write_text(json.dumps(spec))
    data = path.read_bytes()
    _edit_meta(entry, lambda meta: meta["table"].__setitem__(f"{name}/zarr.json",
                                                             [len(data), hashlib.sha256(data).hexdigest()]))


@pytest.mark.parametrize("damage", DAMAGES, ids=list(DAMAGES))
def test_a_damaged_entry_is_recomputed_and_replaced_never_shown(folder, monkeypatch, damage):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    expected = stack_cache.cached_stacks(dataset, REQUEST)
    (name,) = entry_folders()
    entry = stack_cache.cache_folder() / name
    DAMAGES[damage](entry)
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), expected)
    assert computed.stacks == 2
    # the entry was written again, intact: the next request reads it
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), expected)
    assert computed.stacks == 2


def entry_folders_by_request(dataset, requests):
    return [stack_cache._key(dataset, "stacks", dataclasses.asdict(request))[:32] for request in requests]


def test_the_cache_keeps_the_most_recently_used_entries_within_its_bound(folder, monkeypatch):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    requests = [REQUEST.with_changes(stop=stop) for stop in (1.0, 2.0, 3.0)]
    stack_cache.cached_stacks(dataset, requests[0])
    size = sum(os.path.getsize(os.path.join(parent, name))
               for parent, _, names in os.walk(stack_cache.cache_folder()) for name in names)
    monkeypatch.setenv("RINGLIGHT_STACK_CACHE", str(int(2.5 * size)))  # two entries of about this size
    root = stack_cache.cache_folder()
    (root / "mine.txt").write_text("a user's file")
    (root / "not-an-entry").mkdir()
    abandoned = root / f".{'a' * 32}.partial-{'b' * 12}"  # what a killed save left (no lock held)
    abandoned.mkdir()
    monkeypatch.setattr(staging_locks, "ABANDONED_AGE", 0.0)

    stack_cache.cached_stacks(dataset, requests[1])
    for age, name in zip((300, 200), entry_folders_by_request(dataset, requests[:2])):
        os.utime(root / name, (time.time() - age, time.time() - age))
    stack_cache.cached_stacks(dataset, requests[0])  # read: now the most recently used
    assert computed.stacks == 2
    stack_cache.cached_stacks(dataset, requests[2])  # saving it removes requests[1]'s entry
    assert computed.stacks == 3
    stack_cache.cached_stacks(dataset, requests[0])
    stack_cache.cached_stacks(dataset, requests[2])
    assert computed.stacks == 3
    stack_cache.cached_stacks(dataset, requests[1])
    assert computed.stacks == 4
    assert (root / "mine.txt").read_text() == "a user's file" and (root / "not-an-entry").is_dir()
    assert not abandoned.exists()


def test_a_full_disk_leaves_the_stacks_uncached(folder, monkeypatch):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)

    class Full:
        free = stack_cache.SPARE_BYTES

    monkeypatch.setattr(stack_cache.shutil, "disk_usage", lambda path: Full)
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), compute_stacks(dataset, REQUEST))
    assert computed.stacks == 1 and entry_folders() == []


def test_the_explorer_reopens_a_dataset_with_its_saved_stacks_and_noise(folder, monkeypatch):
    from ringlight.app.noise_view import compute_view_noise
    from ringlight.app.session import load_for_viewing

    computed = Computations(monkeypatch)
    first = load_for_viewing(folder, REQUEST, lambda fraction: None)
    first_noise = compute_view_noise(first.dataset, first.stacks.pair, lambda fraction: None)
    again = load_for_viewing(folder, REQUEST, lambda fraction: None)
    noise = compute_view_noise(again.dataset, again.stacks.pair, lambda fraction: None)
    assert (computed.stacks, computed.noise, computed.coverage) == (1, 1, 1)
    assert_same_pair(again.stacks.pair, first.stacks.pair)
    assert_array_equal(again.stacks.poor_coverage, first.stacks.poor_coverage)
    assert again.stacks.coverage_note == first.stacks.coverage_note
    assert_same_noise(noise.noise, first_noise.noise)
    assert_array_equal(noise.snr, first_noise.snr)


def test_a_cache_bound_that_is_not_a_size_is_named_before_any_work_and_0_saves_nothing(folder, monkeypatch):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    for text, why in [("lots", "is not a size"), ("1" + "0" * 400, r"is not a size \(over 8 EiB\)")]:
        monkeypatch.setenv("RINGLIGHT_STACK_CACHE", text)
        with pytest.raises(RinglightError, match=rf"\$RINGLIGHT_STACK_CACHE: '{text[:40]}' {why}"):
            stack_cache.cached_stacks(dataset, REQUEST)
    assert computed.stacks == 0
    monkeypatch.setenv("RINGLIGHT_STACK_CACHE", "0")
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), compute_stacks(dataset, REQUEST))
    stack_cache.cached_noise(dataset, REQUEST)
    assert (computed.stacks, computed.noise, entry_folders()) == (1, 1, [])


@pytest.mark.parametrize("kind", ["noise", "coverage"])
def test_damaged_noise_and_coverage_entries_are_recomputed_too(folder, monkeypatch, kind):
    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    load = {"noise": stack_cache.cached_noise, "coverage": stack_cache.cached_coverage}[kind]
    expected = load(dataset, REQUEST)
    (name,) = entry_folders()
    entry = stack_cache.cache_folder() / name
    array = {"noise": "transient_luminance", "coverage": "nearest_offset"}[kind]
    chunk = next(path for path in (entry / array / "c").rglob("*") if path.is_file())
    _lose(entry, chunk)
    again = load(dataset, REQUEST)
    assert getattr(computed, kind) == 2
    for field in ("radii", "transient_luminance", "ring") if kind == "noise" else ("radii", "nearest_offset"):
        assert_array_equal(getattr(again, field), getattr(expected, field))
    _flip(chunk)  # the entry written again: a flipped byte in it fails its check
    load(dataset, REQUEST)
    assert getattr(computed, kind) == 3


def test_two_threads_settling_zarr_reads_at_once_both_return():
    """Two workers missing or failing a read at once each waited on the other's settle for good
    (found by a review: two cache misses hung the explorer's stacks and noise jobs)."""
    from ringlight.core.dataset.store_table import settle_reads

    for _ in range(50):
        barrier, done = threading.Barrier(2), []

        def settle():
            barrier.wait()
            settle_reads()
            done.append(True)

        threads = [threading.Thread(target=settle, daemon=True) for _ in range(2)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=10)
        assert done == [True, True]


@pytest.fixture
def deep_chains(tmp_path_factory):
    """Removes what a test leaves under the user cache with ``rm -rf``: pytest's own clean-up
    recurses, and chains of 1500 folders defeat it."""
    yield
    subprocess.run(["rm", "-rf", str(stack_cache.cache_folder().parent)], check=False)


def test_planted_entries_are_recomputed_and_nothing_of_the_users_is_touched(folder, monkeypatch, tmp_path, deep_chains):
    """From a fuzz campaign of the cache: another request's entry under this one's name (its
    meta.json's key edited), a chunk whose size the table was edited to 4 GiB (never read), a
    chain of 1500 folders in an entry (Python's os.walk and rmtree recurse); a user's folder of 32
    hex digits in stacks/ is never trimmed, and a stacks/ that links to a user's folder is never
    written, read or trimmed."""
    from ringlight.core.dataset import store_table

    computed = Computations(monkeypatch)
    dataset = open_dataset(folder, radius=6)
    other = REQUEST.with_changes(dr=2.0)
    expected, expected_other = stack_cache.cached_stacks(dataset, REQUEST), stack_cache.cached_stacks(dataset, other)
    root = stack_cache.cache_folder()
    name, other_name = entry_folders_by_request(dataset, [REQUEST, other])
    # another request's entry, its key edited
    shutil.rmtree(root / name)
    shutil.copytree(root / other_name, root / name)
    _edit_meta(root / name, lambda meta: meta.update(key=stack_cache._key(dataset, "stacks",
                                                                          dataclasses.asdict(REQUEST))))
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), expected)
    assert computed.stacks == 3
    # a chunk grown to a 4 GiB sparse file, its size in the table
    chunk = _chunk(root / name, "ring_images", 1)
    with open(chunk, "r+b") as handle:
        handle.truncate(4 * 2**30)
    _edit_meta(root / name, lambda meta: meta["table"][chunk.relative_to(root / name).as_posix()].__setitem__(
        0, 4 * 2**30))
    read = []
    original = store_table.read_checked
    monkeypatch.setattr(store_table, "read_checked", lambda folder, relative, table: (
        read.append(relative), original(folder, relative, table))[1])
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), expected)
    assert computed.stacks == 4 and chunk.relative_to(root / name).as_posix() not in read
    monkeypatch.setattr(store_table, "read_checked", original)
    # a chain of 1500 folders in the entry (replaced when it is written again) and in another one
    # (measured when the cache is trimmed)
    for entry in (root / name, root / other_name):
        path = str(entry)
        for _ in range(1500):  # not os.makedirs, which recurses too
            path = os.path.join(path, "d")
            os.mkdir(path)
    _flip(_chunk(root / name, "ring_images", 0))
    monkeypatch.setenv("RINGLIGHT_STACK_CACHE", "1")  # every save trims the others
    assert_same_pair(stack_cache.cached_stacks(dataset, REQUEST), expected)
    assert computed.stacks == 5
    # a user's folder named like an entry, with a meta.json, is not the cache's to trim
    mine = root / ("ab" * 16)
    mine.mkdir()
    (mine / "meta.json").write_text('{"key": "mine"}')
    (mine / "data.csv").write_text("precious")
    stack_cache.cached_stacks(dataset, REQUEST.with_changes(stop=2.0))
    assert (mine / "data.csv").read_text() == "precious"
    # stacks/ as a link to a user's folder
    subprocess.run(["rm", "-rf", str(root)], check=True)  # the chains left behind defeat rmtree
    users = tmp_path / "users"
    (users / ("cd" * 16)).mkdir(parents=True)
    (users / ("cd" * 16) / "meta.json").write_text('{"key": "' + "cd" * 32 + '"}')
    (users / "thesis.tex").write_text("precious")
    root.symlink_to(users, target_is_directory=True)
    before = sorted(path.relative_to(users).as_posix() for path in users.rglob("*"))
    assert_same_pair(stack_cache.cached_stacks(dataset, other), expected_other)
    assert computed.stacks == 7
    assert sorted(path.relative_to(users).as_posix() for path in users.rglob("*")) == before
