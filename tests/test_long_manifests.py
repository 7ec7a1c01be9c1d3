"""Long manifests (issue 40, case 12): the work per frame after the parse is bounded by counts:
each folder on the way to the frames is resolved once, not every frame's path; a stack whose
rings reach beyond the dataset's max_radius is refused before any frame is read."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from reference import write_rgb
from ringlight.app.main import main
from ringlight.core import load_manifest
from ringlight.core.dataset.checks import check_files


@pytest.fixture
def long_dataset(tmp_path):
    """1 000 frames on a 10 x 10 grid (each point lit in 10 frames), hard links of a few files."""
    folder = tmp_path / "long"
    (folder / "frames").mkdir(parents=True)
    write_rgb(folder / "frames" / "base.exr", np.ones((10, 10, 3), np.float32))
    frames = []
    for index in range(1000):
        name = f"frames/{index:06d}.exr"
        os.link(folder / "frames" / "base.exr", folder / name)
        frames.append({"file": name, "lit": [[(index // 10) % 10, index % 10]], "exposure": 1.0})
    import json

    (folder / "dataset.json").write_text(json.dumps({
        "format": "ringlight-impulse", "version": 1, "grid": {"height": 10, "width": 10}, "max_radius": 3,
        "frames": frames}))
    return folder


def counted(monkeypatch, module, name, record):
    """Replace ``module.name`` by a wrapper that appends ``record(*args)`` to the returned list."""
    calls, original = [], getattr(module, name)

    def wrapper(*args, **kwargs):
        calls.append(record(*args))
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, wrapper)
    return calls


def compiled_visits(monkeypatch, module, name, folder, calls=None):
    """Replace the compiled call ``module.name`` (:func:`ringlight.core.dataset.native_files.read_files`
    or ``stat_files``, which visit files from compiled code, where no Python call can be counted)
    by a wrapper that appends the path of each file it visited (not those it hands back, which are
    visited from Python and counted there), to ``calls`` when given."""
    from ringlight.core.dataset.native_files import HANDED_BACK

    calls, original = [] if calls is None else calls, getattr(module, name)

    def wrapper(descriptor, names, name_starts, *args):
        result = original(descriptor, names, name_starts, *args)
        # read_files(..., inside, flags, limit, header, data, used, starts, sizes, identities, scratch);
        # stat_files(..., identities, missed, scratch)
        visited = args[7] != HANDED_BACK if name == "read_files" else ~args[1]
        text = bytes(names).split(b"\0")
        calls.extend(os.path.join(folder, os.fsdecode(text[index])) for index in np.flatnonzero(visited))
        return result

    monkeypatch.setattr(module, name, wrapper)
    return calls


def test_each_folder_on_the_way_to_the_frames_is_resolved_once(long_dataset, monkeypatch):
    """Path.resolve walked every component of every frame's path twice (20 of the 30 s info took
    over 100 000 frames); now once per folder, and the answers are the same."""
    resolved = []
    original = Path.resolve

    def counted(self, *args, **kwargs):
        resolved.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Path, "resolve", counted)
    manifest = load_manifest(long_dataset)
    resolved.clear()
    assert check_files(manifest) == []
    assert len(resolved) <= 4  # the dataset folder and frames/, with room for the first frame's channels
    outside = long_dataset.parent / "elsewhere.exr"
    write_rgb(outside, np.ones((10, 10, 3), np.float32))
    (long_dataset / "frames" / "000999.exr").unlink()
    (long_dataset / "frames" / "000999.exr").symlink_to(outside)
    problems = check_files(manifest)
    assert problems == [f"{long_dataset}/frames/000999.exr: resolves to {outside}, outside the dataset folder "
                        f"{long_dataset}; allow files outside it explicitly (--allow-outside) to read it"]


def test_a_stack_beyond_max_radius_reads_no_frame(long_dataset, tmp_path, capsys, monkeypatch):
    """A 100 000-frame dataset was opened (25 s of CPU) before its rings were found too large."""
    from ringlight.core.dataset import file_batch
    from ringlight.core.dataset.file_paths import FileResolver

    # Every frame read is opened by the resolver (alone) or the compiled call (in a run).
    reads = compiled_visits(monkeypatch, file_batch, "read_files", long_dataset)
    original = FileResolver.open
    monkeypatch.setattr(FileResolver, "open", lambda self, *args, **kwargs: (reads.append(1),
                                                                            original(self, *args, **kwargs))[1])
    status = main(["stack", str(long_dataset), "--radii", "0:3:1", "--out", str(tmp_path / "out")])
    assert status == 2 and reads == []
    assert capsys.readouterr().err.strip() == (f"ringlight: error: {long_dataset}: the ring of radius 3 (thickness 1) "
                                               "reaches 3.162 grid steps, beyond the dataset's max_radius 3; transient "
                                               "radii (dr 1) up to 1 work (radii 0:1:1)")
    status = main(["stack", str(long_dataset), "--radii", "0:2:1", "--kind", "ring", "--out", str(tmp_path / "out")])
    assert status == 0 and len(reads) >= 1000


def test_each_frame_file_is_opened_once_and_a_shared_header_read_by_the_library_once(long_dataset, monkeypatch):
    """check_files opened each frame three times (its magic, the library's header, its chunk
    table) and had the library parse every header (about 100 us a frame): now one open a frame,
    and the library reads the header the 1000 frames share once (the first frame's channels
    take one more); the chunk tables of the frames that share it are checked in one compiled call
    a run of 1024."""
    import OpenEXR
    from ringlight.core.dataset import exr as exr_module

    manifest = load_manifest(long_dataset)
    opened, parsed = [], []
    original_open, original_file = os.open, OpenEXR.File
    monkeypatch.setattr(exr_module.os, "open", lambda path, *args, **kwargs: (
        opened.append(os.fspath(path)), original_open(path, *args, **kwargs))[1])
    monkeypatch.setattr(OpenEXR, "File", lambda *args, **kwargs: (parsed.append(args[0]),
                                                                   original_file(*args, **kwargs))[1])
    from ringlight.core.dataset import checks, file_batch

    tables = counted(monkeypatch, checks, "chunk_tables_fit", lambda data, starts, sizes, *args: len(sizes))
    compiled_visits(monkeypatch, file_batch, "read_files", long_dataset, opened)
    assert check_files(manifest) == []
    frame_opens = [path for path in opened if "/frames/" in path]
    # Each frame once; the first one once more, for its channels (the library's header read opens
    # it by name, but not through os.open: its magic number is read from the check's own opening).
    assert len(frame_opens) == 1000 + 1
    assert len(set(frame_opens)) == 1000
    assert len(parsed) <= 2, parsed
    assert tables == [999]  # the frames after the first, whose header they share: one compiled call


def test_a_frame_whose_header_differs_from_the_shared_one_is_still_refused(long_dataset):
    """The shared header is known by its bytes: a frame of another size (or a truncated one) after
    999 good ones is checked in full."""
    write_rgb(long_dataset / "frames" / "other.exr", np.ones((10, 11, 3), np.float32))
    (long_dataset / "frames" / "000500.exr").unlink()
    os.link(long_dataset / "frames" / "other.exr", long_dataset / "frames" / "000500.exr")
    data = (long_dataset / "frames" / "base.exr").read_bytes()
    (long_dataset / "frames" / "000700.exr").unlink()
    (long_dataset / "frames" / "000700.exr").write_bytes(data[:-20])
    problems = check_files(load_manifest(long_dataset))
    assert problems == [
        f"{long_dataset}/frames/000500.exr: frame is 10 x 11, expected 10 x 10 (the size of the grid)",
        f"{long_dataset}/frames/000700.exr: truncated or corrupt OpenEXR file (the file ends at byte "
        f"{len(data) - 20}, before the end of its last chunk)"]


def one_point_manifest(folder: Path, frames: int, width: int = 400) -> Path:
    """A manifest of ``frames`` frames lighting one point each, row by row (no frame files)."""
    import json

    folder.mkdir()
    entries = [{"file": f"frames/{i:06d}.exr", "lit": [[i // width, i % width]], "exposure": 1.0}
               for i in range(frames)]
    (folder / "dataset.json").write_text(json.dumps({"format": "ringlight-impulse", "version": 1,
                                                     "grid": {"height": -(-frames // width), "width": width},
                                                     "frames": entries}))
    return folder


def multiplexed_manifest(folder: Path, side: int = 1000, step: int = 5) -> Path:
    """25 frames lighting a 5-step lattice each: a million lit points on a 1000 x 1000 grid."""
    import json

    folder.mkdir()
    frames = [{"file": f"frames/{py}_{px}.exr",
               "lit": [[y, x] for y in range(py, side, step) for x in range(px, side, step)]}
              for py in range(step) for px in range(step)]
    (folder / "dataset.json").write_text(json.dumps({"format": "ringlight-impulse", "version": 1, "max_radius": 2,
                                                     "grid": {"height": side, "width": side}, "frames": frames}))
    return folder


@pytest.fixture(scope="module")
def multiplexed(tmp_path_factory) -> Path:
    """:func:`multiplexed_manifest`'s folder, written once for the module's tests (not to be changed)."""
    return multiplexed_manifest(tmp_path_factory.mktemp("multiplexed") / "m")


def traced_peak_of(function):
    """(result, peak bytes of Python allocations while ``function()`` ran)."""
    import tracemalloc

    tracemalloc.start()
    try:
        result = function()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_long_manifest_is_read_in_memory_a_few_times_its_size(tmp_path, multiplexed):
    """Each frame's JSON objects become a row of the frame table as they are decoded: 100 000
    one-point frames (6.5 MiB of JSON) peaked at 97 MiB of Python allocations (the whole decoded
    document, then a frame object and array view each), now at 25; a million multiplexed points
    (11 MiB) at 248 MiB, now at 61 (the point checks run 2^18 points at a time)."""
    from ringlight.core.dataset.manifest import read_manifest

    read_manifest(one_point_manifest(tmp_path / "warm", 10))  # lazy imports and caches, counted once
    folder = one_point_manifest(tmp_path / "one", 100_000)
    manifest, peak = traced_peak_of(lambda: read_manifest(folder))
    assert peak < 40 * 2**20, peak / 2**20
    assert len(manifest.frames) == 100_000 and manifest.frames[12_345].lit.tolist() == [[30, 345]]
    assert (manifest.lit_counts() == 1).all()
    manifest, peak = traced_peak_of(lambda: read_manifest(multiplexed))
    assert peak < 100 * 2**20, peak / 2**20
    assert len(manifest.frames) == 25 and manifest.frames.counts.tolist() == [40_000] * 25
    assert manifest.frames[7].lit[:2].tolist() == [[1, 2], [1, 7]]  # frame 7: phase (1, 2) of the lattice
    assert (manifest.lit_counts() == 1).all()


def test_the_checks_of_a_long_manifest_still_name_the_first_frame_at_fault(tmp_path, multiplexed):
    """The points are checked in runs of frames: a fault in a later run is found and named."""
    import json

    from ringlight.core import DatasetError
    from ringlight.core.dataset.manifest import read_manifest

    folder = tmp_path / "m"
    folder.mkdir()
    document = json.loads((multiplexed / "dataset.json").read_text())
    document["frames"][20]["lit"][30_000] = [1, 0]  # frame 20 lights [4, 0], 3 away; a duplicate point next
    document["frames"][23]["lit"][39_999] = document["frames"][23]["lit"][0]
    (folder / "dataset.json").write_text(json.dumps(document))
    message = str(pytest.raises(DatasetError, read_manifest, folder).value)
    assert message == (f"{folder}/dataset.json: frames[23] (frames/4_3.exr) lists a lit point twice")
    document["frames"][23]["lit"][39_999] = [999, 998]
    (folder / "dataset.json").write_text(json.dumps(document))
    message = str(pytest.raises(DatasetError, read_manifest, folder).value)
    assert message == (f"{folder}/dataset.json: frames[20] (frames/4_0.exr) lights [4, 0] and [1, 0] 3 apart; "
                       "multiplexed points must be more than 2 * max_radius = 4 apart")


def test_an_open_visits_each_frame_file_once(long_dataset, monkeypatch):
    """An open located, checked and read each frame in four openings of it (an lstat, its magic,
    the library's header, its chunk table) before the library decoded it: now ringlight opens
    each frame once, and the library reads the header the frames share a few times in all (the
    first frame's channels and checks), then only decodes. The responses are the frames' own."""
    import OpenEXR
    from ringlight.core import open_dataset
    from ringlight.core.dataset import file_batch

    opened = compiled_visits(monkeypatch, file_batch, "read_files", long_dataset)
    headers = []
    original_open, original_file = os.open, OpenEXR.File
    monkeypatch.setattr(os, "open", lambda path, *args, **kwargs: (
        opened.append(os.fspath(path)), original_open(path, *args, **kwargs))[1])
    monkeypatch.setattr(OpenEXR, "File", lambda *args, **kwargs: (
        headers.append(args[0]) if kwargs.get("header_only") else None, original_file(*args, **kwargs))[1])
    dataset = open_dataset(long_dataset, use_cache=False)
    frame_opens = [path for path in opened if "/frames/" in path]
    assert len(set(frame_opens)) == 1000
    assert len(frame_opens) <= 1000 + 5, len(frame_opens)
    assert len(headers) <= 3, headers
    # Every point is lit in 10 frames of value 1: each response is their mean, 1.
    assert np.allclose(dataset.point(4, 4)[0], 1.0) and (dataset.lit_counts == 10).all()


def test_a_first_open_stats_no_frame_and_decodes_them_in_a_compiled_call_a_run(long_dataset, monkeypatch):
    """The store's key stat'ed every frame before the frames were read (a second visit of each),
    and each frame took three compiled calls and 35 us of Python: now a first open stats no frame
    (the key's file part is each frame's fstat as it is read), reads the frames after the first in
    runs decoded in one compiled call each (a group of frames a task: 8 with 2 reader threads), and
    a reopen stats each frame once and opens none (the store keeps the channels the first frame's
    header told)."""
    from ringlight.core import open_dataset
    from ringlight.core.dataset import assembly, cache, file_batch, frame_batch
    from ringlight.core.dataset.frames import FrameReader

    monkeypatch.setattr(assembly, "reader_count", lambda: 2)  # 1000 frames in 8 groups of 125
    stats = counted(monkeypatch, os, "stat", lambda path, *args: os.fspath(path))
    compiled_visits(monkeypatch, cache, "stat_files", long_dataset, stats)
    opens = counted(monkeypatch, os, "open", lambda path, *args: os.fspath(path))
    compiled_visits(monkeypatch, file_batch, "read_files", long_dataset, opens)
    runs = counted(monkeypatch, frame_batch, "_load_frames", lambda *args: len(args[2]))
    alone = counted(monkeypatch, FrameReader, "read", lambda reader, frame, *args: frame.file)
    first = open_dataset(long_dataset)
    assert [path for path in stats if "/frames/" in path] == []
    frame_opens = [path for path in opens if "/frames/" in path]
    assert len(set(frame_opens)) == 1000 and len(frame_opens) <= 1000 + 3  # the first frame's header and channels
    assert sorted(runs) == [124] + [125] * 7 and alone == ["frames/000000.exr"]  # read before the band is allocated
    stats.clear(), opens.clear(), runs.clear()
    again = open_dataset(long_dataset)
    frame_stats = [path for path in stats if "/frames/" in path]
    assert len(frame_stats) == len(set(frame_stats)) == 1000
    assert [path for path in opens if "/frames/" in path] == [] and runs == []  # the channels from the store
    assert again.cache_key == first.cache_key
    assert again.responses.tobytes() == first.responses.tobytes()
    # Every point is lit in 10 frames of value 1: each response is their mean, 1.
    assert np.allclose(first.point(4, 4)[0], 1.0) and (first.lit_counts == 10).all()


def linked_frames(folder: Path, frames: int = 400, files: int = 7, dark: bool = True) -> Path:
    """``frames`` frames on a 10 x 10 grid (each point lit frames / 100 times, exposures 0.5-4),
    hard links to ``files`` half-float files of random values (ZIP, the writer's), a dark frame."""
    import json

    rng = np.random.default_rng(5)
    (folder / "frames").mkdir(parents=True)
    for index in range(files):
        write_rgb(folder / "frames" / f"base{index}.exr", rng.uniform(0, 2, (10, 10, 3)).astype(np.float32), half=True)
    entries = []
    for index in range(frames):
        name = f"frames/{index:06d}.exr"
        os.link(folder / "frames" / f"base{index % files}.exr", folder / name)
        entries.append({"file": name, "lit": [[(index // 10) % 10, index % 10]],
                        "exposure": [0.5, 1.0, 4.0][index % 3]})
    document = {"format": "ringlight-impulse", "version": 1, "grid": {"height": 10, "width": 10}, "max_radius": 3,
                "frames": entries}
    if dark:
        write_rgb(folder / "dark.exr", rng.uniform(0, 0.01, (10, 10, 3)).astype(np.float32))
        document["dark"] = "dark.exr"
    (folder / "dataset.json").write_text(json.dumps(document))
    return folder


def test_frames_decoded_in_runs_give_the_responses_of_frames_read_one_by_one(tmp_path, monkeypatch):
    """The reference: the same open with every frame read alone (each decode checked bit for bit
    against the OpenEXR library in test_exr_small), dark frame and exposures included."""
    from ringlight.core import open_dataset
    from ringlight.core.dataset import frame_batch

    folder = linked_frames(tmp_path / "ds")
    runs = counted(monkeypatch, frame_batch, "_load_frames", lambda *args: len(args[2]))
    in_runs = open_dataset(folder, use_cache=False)
    assert sum(runs) == 399
    monkeypatch.setattr(frame_batch, "NATIVE_INFLATE", False)  # no run: each frame alone
    runs.clear()
    alone = open_dataset(folder, use_cache=False)
    assert runs == []
    assert in_runs.responses.tobytes() == alone.responses.tobytes()
    assert in_runs.steady.tobytes() == alone.steady.tobytes()
    assert np.count_nonzero(in_runs.responses) > 100 * 20  # light at every point, from every offset inside


@pytest.mark.parametrize("damage", ["truncated", "other size", "missing", "NaN", "exposure", "truncated, then missing"])
def test_a_frame_at_fault_in_a_run_is_named_as_when_frames_were_read_one_by_one(tmp_path, damage):
    """A run hands back a frame it cannot take, and the frame read alone says what is wrong; a
    frame that cannot be opened ends its run: the first frame at fault in the manifest is named,
    as before."""
    import json

    from ringlight.core import DatasetError, open_dataset

    folder = linked_frames(tmp_path / "ds", dark=False)
    frames = folder / "frames"
    data = (frames / "base0.exr").read_bytes()
    if damage.startswith("truncated"):
        (frames / "000300.exr").unlink()
        (frames / "000300.exr").write_bytes(data[:-20])
        expected = (f"{frames}/000300.exr: truncated or corrupt OpenEXR file (the file ends at byte "
                    f"{len(data) - 20}, before the end of its last chunk)")
    if damage.endswith("missing"):
        (frames / "000333.exr").unlink()
        if damage == "missing":
            expected = f"{frames}/000333.exr: file not found"
    if damage == "other size":
        (frames / "000300.exr").unlink()
        write_rgb(frames / "000300.exr", np.ones((10, 11, 3), np.float32), half=True)
        expected = f"{frames}/000300.exr: frame is 10 x 11, expected 10 x 10 (the size of the grid)"
    if damage == "NaN":
        (frames / "000300.exr").unlink()
        write_rgb(frames / "000300.exr", np.full((10, 10, 3), np.nan, np.float32), half=True)
        expected = f"{frames}/000300.exr: NaN or Inf radiance (300 values in 1 frame(s); this is the first)"
    if damage == "exposure":
        (frames / "000300.exr").unlink()
        write_rgb(frames / "000300.exr", np.full((10, 10, 3), 10, np.float32), half=True)
        document = json.loads((folder / "dataset.json").read_text())
        document["frames"][300]["exposure"] = 1.2e-38  # 10 / 1.2e-38 is beyond float32's 3.4e38
        (folder / "dataset.json").write_text(json.dumps(document))
        expected = f"{frames}/000300.exr: dividing by the exposure 1.2e-38 takes values out of float32's range"
    message = str(pytest.raises(DatasetError, open_dataset, folder, use_cache=False).value)
    assert message == expected


def test_missing_frames_are_said_in_order_without_a_run_each(long_dataset, monkeypatch):
    """A frame that could not be opened ended its run, so 10^6 missing frames made 10^6 runs (each
    with its fixed cost): now its error is kept in its place and the run goes on, and ``info``
    still says every missing frame, in the manifest's order, between the others' problems."""
    from ringlight.core.dataset import checks

    for index in range(100, 1000, 3):
        (long_dataset / "frames" / f"{index:06d}.exr").unlink()
    data = (long_dataset / "frames" / "base.exr").read_bytes()
    (long_dataset / "frames" / "000101.exr").unlink()
    (long_dataset / "frames" / "000101.exr").write_bytes(data[:-20])
    runs = counted(monkeypatch, checks, "read_run", lambda resolver, names, header: len(names))
    problems = check_files(load_manifest(long_dataset))
    assert runs == [999]
    truncated = (f"{long_dataset}/frames/000101.exr: truncated or corrupt OpenEXR file (the file ends at byte "
                 f"{len(data) - 20}, before the end of its last chunk)")
    missing = [f"{long_dataset}/frames/{index:06d}.exr: file not found" for index in range(100, 1000, 3)]
    assert problems == missing[:1] + [truncated] + missing[1:]


def test_runs_read_side_by_side_say_each_problem_in_the_manifests_order(long_dataset, monkeypatch):
    """``info``'s check reads its runs on two threads at once (their system calls from compiled
    code, without the GIL): problems are still said in the manifest's order, each frame visited
    once, exactly as the same check on one thread (the reference, run here) says them; on a
    machine of many cores, at most four threads read (each holds a run's bytes)."""
    import threading

    from ringlight.core.dataset import checks, file_batch

    for index in range(100, 1000, 7):
        (long_dataset / "frames" / f"{index:06d}.exr").unlink()
    data = (long_dataset / "frames" / "base.exr").read_bytes()
    for index in (101, 556, 998):
        (long_dataset / "frames" / f"{index:06d}.exr").unlink()
        (long_dataset / "frames" / f"{index:06d}.exr").write_bytes(data[:-20])
    manifest = load_manifest(long_dataset)
    monkeypatch.setattr(checks, "RUN_FILES", 64)
    monkeypatch.setattr(checks, "reader_count", lambda: 1)
    alone = check_files(manifest)
    monkeypatch.setattr(checks, "reader_count", lambda: 2)
    threads = counted(monkeypatch, checks, "read_run", lambda *args: threading.get_ident())
    visits = compiled_visits(monkeypatch, file_batch, "read_files", long_dataset)
    problems = check_files(manifest)
    assert len(threads) == 16 and len(set(threads)) == 2  # 999 frames in runs of 64, on two threads
    truncated = {index: (f"{long_dataset}/frames/{index:06d}.exr: truncated or corrupt OpenEXR file (the file ends "
                         f"at byte {len(data) - 20}, before the end of its last chunk)") for index in (101, 556, 998)}
    missing = {index: f"{long_dataset}/frames/{index:06d}.exr: file not found" for index in range(100, 1000, 7)}
    assert problems == alone == [{**missing, **truncated}[index] for index in sorted({**missing, **truncated})]
    present = [index for index in range(1, 1000) if index not in missing]
    assert sorted(visits) == [f"{long_dataset}/frames/{index:06d}.exr" for index in present]
    threads.clear()
    monkeypatch.setattr(checks, "reader_count", lambda: 16)  # a larger machine: at most MOST_READERS runs at once
    assert check_files(manifest) == alone and 1 < len(set(threads)) <= checks.MOST_READERS == 4
