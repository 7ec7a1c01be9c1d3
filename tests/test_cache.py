"""The dataset's store: used on reopen, rebuilt when anything changes or it is damaged."""

import json
import os
import time

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from reference import CountingReads, random_impulses, write_dataset, write_rgb
from ringlight.core import open_dataset, ring_stack
from ringlight.core.dataset.cache import CACHE_FOLDER_NAME


@pytest.fixture
def dataset(tmp_path):
    impulses = random_impulses(np.random.default_rng(0), 7, 6, support=10)
    write_dataset(tmp_path / "ds", 7, 6, impulses)
    return tmp_path / "ds"


def test_second_open_reads_the_cache_instead_of_frames(dataset, monkeypatch):
    reads = CountingReads(monkeypatch)
    first = open_dataset(dataset, radius=4)
    assert reads.count == 42
    second = open_dataset(dataset, radius=4)
    assert reads.count == 42
    assert second.store is not None
    assert_array_equal(first.responses, second.responses)
    assert_array_equal(first.steady_state(), second.steady_state())
    assert_array_equal(first.lit_counts, second.lit_counts)


def test_changed_frame_rebuilds_the_cache(dataset, monkeypatch):
    before = ring_stack(open_dataset(dataset, radius=4), [0]).images
    reads = CountingReads(monkeypatch)
    write_rgb(dataset / "frames/00000.exr", np.full((7, 6, 3), 5.0, np.float32))
    after = ring_stack(open_dataset(dataset, radius=4), [0]).images
    assert reads.count == 42
    assert after[0, 0, 0, 0] == 5.0 and before[0, 0, 0, 0] != 5.0


def test_touched_frame_with_same_size_rebuilds_the_cache(dataset, monkeypatch):
    open_dataset(dataset, radius=4)
    reads = CountingReads(monkeypatch)
    later = time.time() + 10
    os.utime(dataset / "frames/00009.exr", (later, later))
    open_dataset(dataset, radius=4)
    assert reads.count == 42


def test_changed_manifest_rebuilds_the_cache(dataset, monkeypatch):
    open_dataset(dataset, radius=4)
    reads = CountingReads(monkeypatch)
    manifest = json.loads((dataset / "dataset.json").read_text())
    manifest["frames"] = manifest["frames"][:-1]
    (dataset / "dataset.json").write_text(json.dumps(manifest))
    reopened = open_dataset(dataset, radius=4)
    assert reads.count == 41
    assert reopened.missing_count == 1


def test_a_different_radius_does_not_reuse_the_cache(dataset, monkeypatch):
    open_dataset(dataset, radius=4)
    reads = CountingReads(monkeypatch)
    assert open_dataset(dataset, radius=2).responses.shape[2] == 13
    assert reads.count == 42


def chunk_files(cache):
    return sorted((cache / "responses").glob("c.*"))


def retable(cache, relative):
    """Record a file's present size and SHA-256 in the store's table, as an edit that knows the
    table would."""
    import hashlib
    meta = json.loads((cache / "meta.json").read_text())
    data = (cache / relative).read_bytes()
    meta["table"][relative] = [len(data), hashlib.sha256(data).hexdigest()]
    (cache / "meta.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("damage", ["truncate", "garbage-meta", "delete-chunk", "delete-array",
                                    "lost chunk and a stray file", "swapped chunks", "chunk copied over another",
                                    "big-endian metadata", "a group for an array", "a huge chunk",
                                    "lost chunk and its row of the table"])
def test_a_damaged_store_is_rebuilt_not_trusted(dataset, monkeypatch, damage):
    """Damage that the folder's walk against the entry's table shows (a missing, extra or resized
    file), or the metadata, rebuilds at open; a chunk moved to another's place fails the table's
    check of it when it is read (here at open: a small dataset is read whole)."""
    from ringlight.core.dataset import response_store
    monkeypatch.setattr(response_store, "CHUNK_BYTES", 4 * 49 * 12)  # 2 x 2 points a chunk: 12 chunks
    truth = np.array(open_dataset(dataset, radius=4).responses)
    cache = dataset / CACHE_FOLDER_NAME
    chunks = chunk_files(cache)
    target = chunks[0]
    metadata = cache / "responses" / "zarr.json"
    if damage == "truncate":
        metadata.write_text("{")
    elif damage == "garbage-meta":
        (cache / "meta.json").write_text("{")
    elif damage == "delete-chunk":
        target.unlink()  # zarr would read a missing chunk as zeros
    elif damage == "lost chunk and a stray file":  # as many files as written
        target.unlink()
        (cache / "responses" / ".DS_Store").write_bytes(b"finder")
    elif damage in ("swapped chunks", "chunk copied over another"):
        same_size = [chunk for chunk in chunks[1:] if chunk.stat().st_size == target.stat().st_size]
        other = same_size[0] if same_size else chunks[1]
        first, second = target.read_bytes(), other.read_bytes()
        target.write_bytes(second)
        if damage == "swapped chunks":
            other.write_bytes(first)
        meta = json.loads((cache / "meta.json").read_text())
        for chunk in (target, other):  # sizes as recorded: only the position check can tell
            meta["table"][chunk.relative_to(cache).as_posix()][0] = chunk.stat().st_size
        (cache / "meta.json").write_text(json.dumps(meta))
    elif damage == "big-endian metadata":
        metadata.write_text(metadata.read_text().replace('"little"', '"big"'))
    elif damage == "a group for an array":
        metadata.write_text(json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {}}))
        retable(cache, "responses/zarr.json")
    elif damage == "lost chunk and its row of the table":  # zarr would read it as its fill value
        target.unlink()
        meta = json.loads((cache / "meta.json").read_text())
        del meta["table"][target.relative_to(cache).as_posix()]
        (cache / "meta.json").write_text(json.dumps(meta))
    elif damage == "a huge chunk":  # 4 GiB, sparse: never read
        with open(target, "r+b") as handle:
            handle.truncate(2**32)
    else:
        (cache / "lit_counts" / "zarr.json").unlink()
    reads = CountingReads(monkeypatch)
    reopened = open_dataset(dataset, radius=4)
    assert reads.count == 42
    assert_array_equal(reopened.responses, truth)


def test_a_flipped_byte_in_a_chunk_fails_its_checksum_and_the_store_is_rebuilt(dataset, monkeypatch):
    truth = np.array(open_dataset(dataset, radius=4).responses)
    cache = dataset / CACHE_FOLDER_NAME
    target = chunk_files(cache)[0]
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0xFF
    target.write_bytes(bytes(data))
    # Small datasets are read whole at open, so the checksum fails there and the store is rebuilt.
    reads = CountingReads(monkeypatch)
    assert_array_equal(open_dataset(dataset, radius=4).responses, truth)
    assert reads.count == 42


def test_a_checksum_failure_while_reading_out_of_core_names_the_store_and_marks_it(dataset, monkeypatch):
    from ringlight.core.errors import DatasetError

    open_dataset(dataset, radius=4, memory_budget_bytes=1)
    cache = dataset / CACHE_FOLDER_NAME
    for target in chunk_files(cache):
        data = bytearray(target.read_bytes())
        data[len(data) // 2] ^= 0xFF
        target.write_bytes(bytes(data))
    lazy = open_dataset(dataset, radius=4, memory_budget_bytes=1)
    assert not lazy.in_memory
    with pytest.raises(DatasetError, match=f"{CACHE_FOLDER_NAME}: damaged cache chunk in rows 0"):
        ring_stack(lazy, [0])
    reads = CountingReads(monkeypatch)
    open_dataset(dataset, radius=4)
    assert reads.count == 42


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores folder permissions")
def test_read_only_dataset_caches_in_the_user_folder(dataset, private_cache):
    os.chmod(dataset, 0o555)
    try:
        open_dataset(dataset, radius=4)
    finally:
        os.chmod(dataset, 0o755)
    assert not (dataset / CACHE_FOLDER_NAME).exists()
    assert any(private_cache.iterdir())


def test_unwritable_dataset_folder_caches_in_the_user_folder(dataset, private_cache, monkeypatch):
    """Same as above for root, who ignores permissions: os.access reports the folder read-only."""
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: False if str(path).startswith(str(dataset)) else real_access(path, mode))
    open_dataset(dataset, radius=4)
    assert not (dataset / CACHE_FOLDER_NAME).exists()
    (entry,) = private_cache.iterdir()
    assert (entry / "meta.json").is_file() and chunk_files(entry)
    reads = CountingReads(monkeypatch)
    open_dataset(dataset, radius=4)
    assert reads.count == 0


def test_cache_can_be_bypassed(dataset):
    open_dataset(dataset, radius=4, use_cache=False)
    assert not (dataset / CACHE_FOLDER_NAME).exists()


def test_the_store_of_a_smooth_half_float_capture_is_smaller_than_its_frames(tmp_path):
    """Offset-major chunks (one offset's responses over neighbouring points, a smooth image)
    compress the store below the EXR frames' size: 0.71x here, where point-major chunks took 1.24x."""
    size, radius = 48, 6
    yy, xx = np.mgrid[0:size, 0:size]
    impulses = {}
    for qy in range(size):
        for qx in range(size):
            distance = np.hypot(yy - qy, xx - qx)
            falloff = np.exp(-distance / 3.0) * (1.0 + 0.2 * np.sin(0.05 * (qy + 2 * qx)))
            falloff[distance > radius] = 0.0
            impulses[(qy, qx)] = (falloff[..., None] * [0.9, 0.6, 0.3]).astype(np.float32)
    write_dataset(tmp_path / "ds", size, size, impulses, max_radius=radius, multiplex=True, half=True)
    opened = open_dataset(tmp_path / "ds")
    frames = sum(path.stat().st_size for path in (tmp_path / "ds" / "frames").iterdir())
    store = sum(path.stat().st_size for path in (tmp_path / "ds" / CACHE_FOLDER_NAME).rglob("*") if path.is_file())
    assert opened.responses is not None and opened.responses.any()
    assert store < 0.85 * frames, (store, frames)


def test_store_tiles_are_whole_multiples_of_16_points_once_8_or_more():
    """A chunk's side: about 8 MB of (K, 3) float32, rounded to a multiple of 16 (the EXR line
    chunks, and whole bit-shuffle blocks per offset image: at 1024 px, R 32, a 14-point side took
    the store to 0.215 of raw float32 and 16 to 0.134), kept below 8, never beyond the grid."""
    from ringlight.core.dataset.disc import disc_offset_count
    from ringlight.core.dataset.response_store import store_tile

    assert store_tile((1024, 1024), disc_offset_count(32)) == 16  # sqrt(8 MiB / (3209 * 12)) = 14.8
    assert store_tile((800, 800), disc_offset_count(24)) == 16  # 19.3
    assert store_tile((512, 512), disc_offset_count(8)) == 64  # 58.3
    assert store_tile((2048, 2048), disc_offset_count(64)) == 7  # 7.4: below 8, kept
    assert store_tile((12, 10), disc_offset_count(4)) == 12  # the grid is smaller than a chunk


KILLED_WRITER = """
import os, sys
from ringlight.core.atomic import atomic_folder
with atomic_folder(sys.argv[1]) as staging:
    (staging / "responses").mkdir()
    (staging / "responses" / "c.0.0.0.0").write_bytes(b"x" * 4096)
    print(staging.name, flush=True)
    if sys.argv[2] == "kill":
        os.kill(os.getpid(), 9)
    sys.stdin.readline()  # holds the staging folder, still writing, until told to go on
"""


def _writer(location, how):
    import subprocess
    import sys
    process = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(location), how],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    return process, process.stdout.readline().strip()


@pytest.mark.parametrize("cached", [False, True])
def test_a_killed_open_leaves_a_temporary_that_the_next_open_removes(dataset, monkeypatch, cached):
    """A process killed while it builds the store (SIGKILL: nothing of its own runs) leaves its
    hidden staging folder beside the cache; the next open removes it, as its lock died with it,
    whether it builds the store (none yet) or reads a current one."""
    import ringlight.core.staging_locks as staging_locks
    monkeypatch.setattr(staging_locks, "ABANDONED_AGE", 0.0)
    location = dataset / CACHE_FOLDER_NAME
    if cached:
        open_dataset(dataset)
    process, staging = _writer(location, "kill")
    process.communicate()
    assert process.returncode == -9 and (dataset / staging / "responses" / "c.0.0.0.0").exists()
    reads = CountingReads(monkeypatch)
    open_dataset(dataset)
    assert not (dataset / staging).exists()
    assert (location / "meta.json").exists() and (reads.count == 0) == cached


def test_a_temporary_that_another_process_is_writing_is_left_alone(dataset, monkeypatch):
    import ringlight.core.staging_locks as staging_locks
    monkeypatch.setattr(staging_locks, "ABANDONED_AGE", 0.0)
    location = dataset / CACHE_FOLDER_NAME
    process, staging = _writer(location, "hold")
    try:
        assert staging_locks.sweep_abandoned(location) == []
        open_dataset(dataset)
        assert (dataset / staging / "responses" / "c.0.0.0.0").exists()
    finally:
        process.communicate("go on\n")
    assert process.returncode == 0 and not (dataset / staging).exists()


def test_only_ringlights_abandoned_cache_folders_are_swept(dataset, monkeypatch):
    """Files, links and other names, a young temporary (made just before its writer locks it) and
    anything when locks are missing are never removed."""
    import ringlight.core.staging_locks as staging_locks
    location = dataset / CACHE_FOLDER_NAME
    old_entry = dataset / "..ringlight-cache.old-0123456789ab"
    (old_entry / "responses").mkdir(parents=True)
    young = dataset / "..ringlight-cache.partial-abcdefabcdef"
    young.mkdir()
    kept = {
        "..ringlight-cache.partial-0123456789ab": "file",  # a file, not a folder
        "..ringlight-cache.partial-aaaaaaaaaaaa": "link",  # a link to the user's folder
        "..ringlight-cache.partial-0123": "folder",  # not a temporary's name
        ".thesis.partial-0123456789ab": "folder",  # another name's temporary
        "..ringlight-cache.partial-0123456789abX": "folder",
    }
    user = dataset / "mine"
    user.mkdir()
    (user / "notes.txt").write_text("keep")
    for name, kind in kept.items():
        if kind == "file":
            (dataset / name).write_text("keep")
        elif kind == "link":
            (dataset / name).symlink_to(user, target_is_directory=True)
        else:
            (dataset / name).mkdir()
    monkeypatch.setattr(staging_locks, "fcntl", None)
    assert staging_locks.sweep_abandoned(location, min_age=0.0) == []
    monkeypatch.undo()
    assert staging_locks.sweep_abandoned(location, min_age=3600.0) == []  # all of them made just now
    assert sorted(staging_locks.sweep_abandoned(location, min_age=0.0)) == sorted([old_entry.name, young.name])
    assert not old_entry.exists() and not young.exists()
    for name in kept:
        assert os.path.lexists(dataset / name), name
    assert (user / "notes.txt").read_text() == "keep"


def test_a_store_replaced_by_another_open_fails_its_old_reader_and_stays_valid(dataset, monkeypatch):
    """An open at another radius replaces the entry (one folder a dataset): a dataset opened
    before it can no longer read its responses (one line), and its failure does not mark the new
    entry stale."""
    from ringlight.core.errors import DatasetError

    old = open_dataset(dataset, radius=4, memory_budget_bytes=1)
    open_dataset(dataset, radius=3, memory_budget_bytes=1)  # writes the entry anew
    with pytest.raises(DatasetError, match="damaged cache chunk"):
        ring_stack(old, [0])
    reads = CountingReads(monkeypatch)
    again = open_dataset(dataset, radius=3, memory_budget_bytes=1)
    assert reads.count == 0 and again.store is not None


@pytest.mark.parametrize("errno_name, written", [("ENOLCK", True), ("EMFILE", False)])
def test_a_store_is_written_unlocked_only_where_the_file_system_has_no_locks(dataset, monkeypatch, errno_name,
                                                                            written):
    """A staging folder that could not be locked would look abandoned to another process's sweep
    a minute on: it is written unlocked only on a file system without locks (where no sweep can
    lock it either); any other failure to lock fails the write, leaving nothing."""
    import errno

    import ringlight.core.staging_locks as staging_locks
    from ringlight.core.atomic import OutputError, atomic_folder

    def refuse(descriptor, operation):
        raise OSError(getattr(errno, errno_name), os.strerror(getattr(errno, errno_name)))

    monkeypatch.setattr(staging_locks.fcntl, "flock", refuse)
    location = dataset / "entry"
    if written:
        with atomic_folder(location) as staging:
            (staging / "a").write_text("1")
        assert (location / "a").read_text() == "1"
    else:
        with pytest.raises(OutputError, match="entry: cannot write here"):
            with atomic_folder(location) as staging:
                (staging / "a").write_text("1")
        assert not location.exists()
    assert not [name for name in os.listdir(dataset) if ".partial-" in name]


def test_a_cache_entry_linked_elsewhere_is_neither_measured_nor_followed(tmp_path):
    """The free-space check adds the space of the entry it replaces: a user-cache entry planted as a
    link to ``/`` made it walk the whole disk (found by a fuzz campaign). The link counts nothing
    (:func:`ringlight.core.atomic.atomic_folder` removes such a link, never follows it)."""
    from ringlight.core.dataset.response_store import entry_bytes

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "big").write_bytes(b"x" * 4096)
    link = tmp_path / "entry"
    link.symlink_to(elsewhere, target_is_directory=True)
    assert entry_bytes(elsewhere) == 4096 and entry_bytes(link) == 0


def test_a_reopen_takes_the_channels_from_the_store_and_edited_ones_rebuild_it(dataset, monkeypatch):
    """A reopen read the first frame's header for the frames' channels: the store keeps them, bound
    to its key, so a reopen opens no frame, and channels edited in its meta.json (a colour
    dataset made monochrome) fail the key and rebuild the store from the frames."""
    first = open_dataset(dataset, radius=4)
    opened = []
    original = os.open
    monkeypatch.setattr(os, "open", lambda path, *args, **kwargs: (opened.append(os.fspath(path)),
                                                                   original(path, *args, **kwargs))[1])
    again = open_dataset(dataset, radius=4)
    assert again.channels == ("R", "G", "B") and [path for path in opened if path.endswith(".exr")] == []
    meta = json.loads((dataset / CACHE_FOLDER_NAME / "meta.json").read_text())
    meta["channels"] = ["R"]
    (dataset / CACHE_FOLDER_NAME / "meta.json").write_text(json.dumps(meta))
    reads = CountingReads(monkeypatch)
    rebuilt = open_dataset(dataset, radius=4)
    assert reads.count == 42 and rebuilt.channels == ("R", "G", "B") and not rebuilt.monochrome
    assert rebuilt.responses.tobytes() == first.responses.tobytes()
