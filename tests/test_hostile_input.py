"""Regression tests for the hostile inputs of issue 11: one test per failure class the fuzzing
campaign found, each checking the one-line message (or, for the cache, that it is rebuilt)."""

import functools
import json
import os
import subprocess
import sys
import tempfile
import tracemalloc
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from reference import (
    CountingReads,
    edit_manifest,
    random_impulses,
    write_dataset,
    write_exr,
    write_rgb,
)
from ringlight.core import DatasetError, open_dataset
from ringlight.core.dataset.cache import CACHE_FOLDER_NAME
from ringlight.core.dataset.checks import check_files
from ringlight.core.dataset.exr import read_exr_rgb
from ringlight.core.dataset.manifest import read_manifest
from ringlight.core.dataset.response_store import LAYOUT_VERSION

MiB = 2**20


@contextmanager
def counted_calls():
    """Count the Python and C function calls made in the block (``sys.setprofile``); the yielded
    list receives the count. A measure of work that does not depend on the machine's load."""
    count = [0]

    def profile(frame, event, arg):
        if event in ("call", "c_call"):
            count[0] += 1

    sys.setprofile(profile)
    try:
        yield count
    finally:
        sys.setprofile(None)


@functools.cache
def warm_readers() -> None:
    """Open a valid dataset once per process: numba's typing registries (about 30 MB of Python
    objects, loaded by the first compiled kernel a process calls) and the readers' kernels are the
    process's, not an open's. Run alone, a test's traced open loaded them: 34 MB against its 16."""
    with tempfile.TemporaryDirectory() as folder:
        open_dataset(write_valid(Path(folder) / "ds"), use_cache=False)


@contextmanager
def traced_peak():
    """Trace Python's allocations in the block (once the readers are warm, :func:`warm_readers`);
    the yielded list receives the peak in bytes."""
    warm_readers()
    peak = []
    tracemalloc.start()
    try:
        yield peak
        peak.append(tracemalloc.get_traced_memory()[1])
    finally:
        tracemalloc.stop()


def write_valid(folder: Path) -> Path:
    """Write a valid 6 x 5 one-point-per-frame dataset (30 frames) into ``folder``; returns it."""
    write_dataset(folder, 6, 5, random_impulses(np.random.default_rng(0), 6, 5, support=10))
    return folder


@pytest.fixture
def dataset(tmp_path):
    """A valid dataset (:func:`write_valid`); tests break one thing each."""
    return write_valid(tmp_path / "ds")


def replace_in_manifest(folder, old, new):
    """Edit the manifest's text: for what json.dumps cannot write (huge integers, NaN, ...)."""
    path = folder / "dataset.json"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def refused(folder, *needles, **options):
    """Open ``folder``; it must raise one DatasetError line holding every needle."""
    with pytest.raises(DatasetError) as caught:
        open_dataset(folder, **options)
    message = str(caught.value)
    assert "\n" not in message and len(message) < 400, message
    for needle in needles:
        assert needle in message, message
    return message


# Manifest: the bounded JSON reader -------------------------------------------------------------

def test_deeply_nested_json_is_refused_not_a_recursion_error(dataset):
    (dataset / "dataset.json").write_text("[" * 100_000 + "]" * 100_000)
    refused(dataset, "dataset.json", "nested too deeply")


def test_an_integer_literal_of_5000_digits_is_refused(dataset):
    replace_in_manifest(dataset, '"version": 1', '"version": ' + "9" * 5000)
    refused(dataset, "dataset.json", "an integer literal of 5000 digits (at most 30)")


def test_a_401_digit_integer_exposure_is_refused_not_an_overflow(dataset):
    replace_in_manifest(dataset, '"lit": [[0, 0]]', '"lit": [[0, 0]], "exposure": 1' + "0" * 400)
    refused(dataset, "dataset.json", "an integer literal of 401 digits")


def test_a_lit_point_beyond_int64_is_outside_the_grid(dataset):
    replace_in_manifest(dataset, '"lit": [[0, 0]]', '"lit": [[' + "9" * 25 + ", 0]]")
    refused(dataset, "dataset.json", "frames[0] (frames/00000.exr) lights [9999999999", "outside the 6 x 5 grid")


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_nan_and_infinity_literals_are_refused(dataset, literal):
    replace_in_manifest(dataset, '"lit": [[0, 0]]', f'"lit": [[0, 0]], "exposure": {literal}')
    refused(dataset, "dataset.json", f"{literal.lstrip('-')} is not a JSON number")


def test_a_float_literal_that_overflows_is_not_a_finite_number(dataset):
    replace_in_manifest(dataset, '"lit": [[0, 0]]', '"lit": [[0, 0]], "exposure": 1e999')
    refused(dataset, "'frames[0].exposure' must be a finite number, got inf")


def test_invalid_utf8_is_refused(dataset):
    (dataset / "dataset.json").write_bytes(b'{"format": "\xff\xfe"}')
    refused(dataset, "dataset.json", "is not UTF-8 text (byte 12)")


def test_a_manifest_over_the_size_limit_is_refused_before_parsing(dataset, monkeypatch):
    from ringlight.core import validation

    monkeypatch.setattr(validation, "MAX_JSON_BYTES", 1000)
    monkeypatch.setattr(validation.read_bounded, "__defaults__", ("JSON file", 1000))
    (dataset / "dataset.json").write_text(" " * 2000 + "{}")
    refused(dataset, "dataset.json", "over the 0 MiB a manifest may have")


@pytest.mark.parametrize("special", ["fifo", "folder"])
def test_a_manifest_that_is_not_a_regular_file_is_never_read(dataset, special):
    (dataset / "dataset.json").unlink()
    if special == "fifo":
        os.mkfifo(dataset / "dataset.json")  # reading it would block forever
    else:
        (dataset / "dataset.json").mkdir()
    refused(dataset, "dataset.json", "the manifest is not a regular file")


# Manifest: values representable, sizes refused by arithmetic ----------------------------------

@pytest.mark.parametrize("exposure", [1e-320, 1e39])
def test_exposures_outside_float32_are_refused(dataset, exposure):
    edit_manifest(dataset, lambda m: m["frames"][3].update(exposure=exposure))
    refused(dataset, "frames[3].exposure", "cannot be represented in float32")


def test_an_exposure_that_overflows_a_frame_is_refused(dataset):
    write_rgb(dataset / "frames/00002.exr", np.full((6, 5, 3), 3e38, np.float32))
    edit_manifest(dataset, lambda m: m["frames"][2].update(exposure=0.5))
    refused(dataset, "frames/00002.exr: dividing by the exposure 0.5 takes values out of float32's range")


def test_an_exposure_that_underflows_a_frame_to_zero_is_refused(dataset):
    write_rgb(dataset / "frames/00002.exr", np.full((6, 5, 3), 1e-30, np.float32))
    edit_manifest(dataset, lambda m: m["frames"][2].update(exposure=1e30))
    refused(dataset, "frames/00002.exr: dividing by the exposure 1e+30 takes values out of float32's range")


def test_a_dark_frame_that_overflows_the_radiance_is_refused(dataset):
    write_rgb(dataset / "frames/00001.exr", np.full((6, 5, 3), 3e38, np.float32))
    write_rgb(dataset / "dark.exr", np.full((6, 5, 3), -3e38, np.float32))
    edit_manifest(dataset, lambda m: m.update(dark="dark.exr"))
    refused(dataset, "frames/00001.exr: subtracting the dark frame takes values out of float32's range")


def test_a_huge_max_radius_or_grid_is_refused_before_any_allocation(dataset):
    edit_manifest(dataset, lambda m: m.update(max_radius=1e300))
    refused(dataset, "'max_radius' 1e+300 is over 1024 grid steps")
    edit_manifest(dataset, lambda m: (m.pop("max_radius"), m.update(grid={"height": 10**6, "width": 10**6})))
    refused(dataset, "grid 1000000 x 1000000 has over 67,108,864 points")


def test_the_grid_diagonal_fallback_is_refused_by_arithmetic(dataset):
    """An 8192 x 8192 grid without max_radius: responses up to the diagonal would need 10**8 GiB;
    refused in milliseconds, with nothing of the grid's size allocated."""
    edit_manifest(dataset, lambda m: m.update(grid={"height": 8192, "width": 8192}))
    with traced_peak() as peak, counted_calls() as calls:
        refused(dataset, "responses up to radius 11583.8 need", "GiB free for its store in", "open with a smaller radius")
    assert peak[0] < 16 * MiB
    # A few thousand calls: reading 30 frame entries and some arithmetic, no per-point loop over
    # the 67 million grid points or the 10^8 offsets the diagonal would need.
    assert calls[0] < 100_000, calls[0]


def test_frames_of_the_wrong_size_fail_before_the_response_array_exists(dataset):
    """A 4096 x 4096 grid at max_radius 2 would build a 2.5 GiB response array (within the memory
    budget): the first frame's header is checked first, so almost nothing is allocated."""
    edit_manifest(dataset, lambda m: m.update(grid={"height": 4096, "width": 4096}, max_radius=2))
    with traced_peak() as peak:
        refused(dataset, "frames/00000.exr: frame is 6 x 5, expected 4096 x 4096 (the size of the grid)",
                use_cache=False)
    assert peak[0] < 16 * MiB


def test_lit_counts_allocates_only_its_int32_result(dataset):
    """(H, W) int32 is 64 MiB for a 4096 x 4096 grid; the old bincount made 128 MiB of int64 first."""
    edit_manifest(dataset, lambda m: m.update(grid={"height": 4096, "width": 4096}))
    manifest = read_manifest(dataset)
    with traced_peak() as peak:
        counts = manifest.lit_counts()
    assert counts.dtype == np.int32 and counts.shape == (4096, 4096)
    assert counts.sum() == 30 and counts[:6, :5].all()  # each of the 6 x 5 points lit once
    assert peak[0] < 64 * MiB + 8 * MiB


# Manifest: file names ---------------------------------------------------------------------------

@pytest.mark.parametrize("name, needle", [
    ("a" * 300 + ".exr", "must be a file name of at most 255 bytes per folder level"),
    ("/".join(["a" * 200] * 30), "must be a path of at most 1024 bytes"),
    ("frames/a\0b.exr", "must be a file name without NUL characters"),
])
def test_file_names_no_file_system_can_hold_are_refused(dataset, name, needle):
    edit_manifest(dataset, lambda m: m["frames"][0].update(file=name))
    refused(dataset, "dataset.json", "'frames[0].file'", needle)


def test_lone_surrogates_are_refused_in_file_names_and_text(dataset):
    replace_in_manifest(dataset, '"frames/00000.exr"', '"frames/\\ud800.exr"')
    refused(dataset, "'frames[0].file' must be a file name in valid Unicode")
    write_valid(dataset)
    replace_in_manifest(dataset, '"version": 1', '"version": 1, "notes": "\\udc80 x"')
    refused(dataset, "'notes' must be a string of valid Unicode")


def test_a_dataset_folder_name_too_long_for_the_os_is_one_line(tmp_path):
    message = str(pytest.raises(DatasetError, open_dataset, tmp_path / ("d" * 300)).value)
    assert "File name too long" in message or "no such dataset folder" in message


# Manifest: size of the parse ------------------------------------------------------------------

def one_point_manifest(folder, frames, width=400):
    """A manifest of ``frames`` frames lighting one point each, row by row on a grid ``width`` wide."""
    folder.mkdir(exist_ok=True)
    entries = [{"file": f"frames/{i:06d}.exr", "lit": [[i // width, i % width]], "exposure": 1.0}
               for i in range(frames)]
    document = {"format": "ringlight-impulse", "version": 1,
                "grid": {"height": -(-frames // width), "width": width}, "frames": entries}
    (folder / "dataset.json").write_text(json.dumps(document))
    return folder


def test_a_manifest_parses_in_work_linear_in_its_frames(tmp_path):
    """The issue measured 51 s for 100,000 frames; the speed is benchmarks/bench_manifest.py's.
    Here the work: Python calls (a deterministic count) grow by at most 60 per added frame (about
    40 now), so a quadratic pass over the frames in Python fails."""
    read_manifest(one_point_manifest(tmp_path / "warm", 10))  # lazy imports and caches, counted once
    counts = []
    for frames in (2_000, 20_000):
        folder = one_point_manifest(tmp_path / f"m{frames}", frames)
        with counted_calls() as calls:
            manifest = read_manifest(folder)
        assert len(manifest.frames) == frames
        counts.append(calls[0])
    assert counts[1] - counts[0] <= 60 * 18_000, counts


# EXR frames, dark and mapping -----------------------------------------------------------------

def set_data_window(path, height, width):
    """Rewrite the dataWindow (and displayWindow) of an EXR header in place: a small file that
    claims a huge image, the shape of a decompression bomb."""
    data = bytearray(path.read_bytes())
    for name in (b"dataWindow\0box2i\0", b"displayWindow\0box2i\0"):
        at = data.index(name) + len(name) + 4
        data[at:at + 16] = np.array([0, 0, width - 1, height - 1], "<i4").tobytes()
    path.write_bytes(bytes(data))


def test_a_frame_header_claiming_a_huge_image_is_refused_before_decoding(dataset):
    set_data_window(dataset / "frames/00004.exr", 8000, 8000)
    with traced_peak() as peak:
        refused(dataset, "frames/00004.exr: frame is 8000 x 8000, expected 6 x 5")
    assert peak[0] < 16 * MiB


def test_a_header_over_the_pixel_limit_is_refused(dataset):
    set_data_window(dataset / "frames/00004.exr", 10_000, 10_000)
    refused(dataset, "frames/00004.exr: the header says 10000 x 10000 pixels, over the 64 megapixels")


def test_a_mapping_header_claiming_a_huge_camera_is_refused_before_decoding(dataset):
    """The mapping's size is known only from its header: its chunk table must fit the file, and
    the first frame must agree with it, before it is decoded."""
    y, x = np.mgrid[:6, :5].astype(np.float32)
    write_exr(dataset / "mapping.exr", {"y": y, "x": x})
    set_data_window(dataset / "mapping.exr", 8000, 8000)
    edit_manifest(dataset, lambda m: m.update(frame_space="camera", mapping="mapping.exr"))
    with traced_peak() as peak:
        refused(dataset, "mapping.exr: truncated or corrupt OpenEXR file (the file ends at byte",
                "inside its table of 500 chunk offsets")
    assert peak[0] < 16 * MiB


def test_a_tiny_camera_under_a_huge_grid_is_refused_before_allocation(dataset):
    """Camera frames can be small while the grid is huge: 30 pixels cannot see 1% of 8192 x 4096
    points, whose response array would hold gigabytes of zeros (found by the fuzz campaign)."""
    y, x = np.mgrid[:6, :5].astype(np.float32)
    write_exr(dataset / "mapping.exr", {"y": y, "x": x})
    edit_manifest(dataset, lambda m: m.update(frame_space="camera", mapping="mapping.exr", max_radius=1.5,
                                              grid={"height": 8192, "width": 4096}))
    with traced_peak() as peak:
        refused(dataset, "mapping.exr: a camera of 6 x 5 pixels cannot see 1% of the 8192 x 4096 grid",
                use_cache=False)
    assert peak[0] < 16 * MiB


@pytest.mark.parametrize("fill", [np.nan, 1e30, -7.0])
def test_a_camera_mapping_that_sees_no_grid_point_is_one_line(dataset, fill):
    write_exr(dataset / "mapping.exr", {"y": np.full((6, 5), fill, np.float32), "x": np.full((6, 5), 1.0, np.float32)})
    edit_manifest(dataset, lambda m: m.update(frame_space="camera", mapping="mapping.exr"))
    refused(dataset, "mapping.exr: no camera pixel maps into the 6 x 5 grid (all NaN or outside)")


def test_a_channel_name_that_is_not_utf8_is_refused_in_one_line(dataset):
    """Found by the fuzz test (byte 28 of frame 0 set to 0x80): the first channel's name, which the
    library decodes only when asked, raised UnicodeDecodeError from reading the first frame's
    channels."""
    path = dataset / "frames/00000.exr"
    data = bytearray(path.read_bytes())
    assert data[28:30] == b"B\0"  # the channel list's first name (sorted: B, G, R)
    data[28] = 0x80
    path.write_bytes(bytes(data))
    refused(dataset, "frames/00000.exr: truncated or corrupt OpenEXR file", "utf-8")


def test_a_subsampled_channel_is_refused_in_the_header(dataset):
    """A channel list entry is name, pixel type (4), pLinear and reserved (4), x and y sampling
    (4 + 4): set R's y sampling to 2 in a valid frame (6 rows divide by 2, so the header is valid)."""
    path = dataset / "frames/00006.exr"
    data = bytearray(path.read_bytes())
    at = data.index(b"R\0", data.index(b"chlist\0")) + 2 + 12
    data[at:at + 4] = (2).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    refused(dataset, "frames/00006.exr: channel(s) R are subsampled; ringlight reads full-resolution channels only")


def chunk_table_start(data):
    """Offset of a single-part EXR's chunk table: after the attributes and their end byte."""
    at = 8
    while data[at] != 0:
        name_end = data.index(b"\0", at)
        type_end = data.index(b"\0", name_end + 1)
        at = type_end + 5 + int.from_bytes(data[type_end + 1:type_end + 5], "little")
    return at + 1


def rewrite_chunk_table(path, count, change):
    """Apply ``change`` to the (count,) uint64 chunk offsets of a single-part EXR."""
    data = bytearray(path.read_bytes())
    start = chunk_table_start(data)
    offsets = np.frombuffer(bytes(data[start:start + 8 * count]), "<u8").copy()
    data[start:start + 8 * count] = change(offsets).astype("<u8").tobytes()
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage, needle", [
    ("truncate", "before the end of its last chunk"),
    ("zero-table", "a chunk offset points outside the file's data"),
    ("cut-in-table", "inside its table of 1 chunk offsets"),
])
def test_truncated_frames_are_found_from_the_chunk_table(dataset, damage, needle):
    path = dataset / "frames/00005.exr"
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:-3])
    elif damage == "zero-table":
        rewrite_chunk_table(path, 1, lambda offsets: offsets * 0)  # ZIP: 16 lines a chunk, so one
    else:
        data = path.read_bytes()
        path.write_bytes(data[:chunk_table_start(data) + 4])
    refused(dataset, "frames/00005.exr: truncated or corrupt OpenEXR file", needle)


@pytest.mark.parametrize("channels, rows", [("RGB", None), ("RGB", (0, 32)), ("RGBA", None)])
def test_the_openexr_librarys_own_output_never_reaches_the_user(tmp_path, channels, rows):
    """A chunk table pointing at the wrong chunk makes OpenEXR print a warning on stdout and a line
    on stderr; the user sees ringlight's one line only, from either of the library's readers (the
    whole-file one for R, G, B read whole; the selecting one for a band of rows or another channel)."""
    y = np.random.default_rng(2).random((64, 64, len(channels))).astype(np.float32)
    path = tmp_path / "frame.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {name: y[..., index].copy() for index, name in enumerate(channels)}) as exr:
        exr.write(str(path))

    def point_chunk_0_at_chunk_1(offsets):  # 64 lines of ZIP: 4 chunks
        offsets[0] = offsets[1]
        return offsets

    rewrite_chunk_table(path, 4, point_chunk_0_at_chunk_1)
    code = ("import sys\nfrom ringlight.core import RinglightError\n"
            "from ringlight.core.dataset.exr import read_exr_channels\n"
            f"try:\n    read_exr_channels({str(path)!r}, ('R', 'G', 'B'), rows={rows!r})\n"
            "except RinglightError as error:\n"
            "    print(error, file=sys.stderr)\n    sys.exit(2)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1, result.stderr
    # The library's own reason, also where its whole-file reader just drops the part it cannot decode.
    assert result.stderr == f"{path}: truncated or corrupt OpenEXR file (Unable to query scanline information)\n"


def test_a_valid_file_reads_exactly(tmp_path):
    """The checks above refuse nothing valid: a tiled and a scanline file read back bit for bit."""
    image = np.random.default_rng(3).random((37, 23, 3)).astype(np.float32)
    for kind in ("scanline", "tiled"):
        header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
        if kind == "tiled":
            tiles = OpenEXR.TileDescription()
            tiles.xSize, tiles.ySize = 8, 4
            header.update(type=OpenEXR.tiledimage, tiles=tiles)
        with OpenEXR.File(header, {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}) as exr:
            exr.write(str(tmp_path / f"{kind}.exr"))
        np.testing.assert_array_equal(read_exr_rgb(tmp_path / f"{kind}.exr", (37, 23)), image)


# Cache ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("meta", ["[]", "null", '{"key": {"a": [[]]}, "crc32": [], "shapes": 3}', '"key"'])
def test_a_meta_json_of_the_wrong_type_rebuilds_the_cache(dataset, monkeypatch, meta):
    truth = np.array(open_dataset(dataset, radius=2).responses)
    (dataset / CACHE_FOLDER_NAME / "meta.json").write_text(meta)
    reads = CountingReads(monkeypatch)
    reopened = open_dataset(dataset, radius=2)
    assert reads.count == 30
    np.testing.assert_array_equal(reopened.responses, truth)
    assert json.loads((dataset / CACHE_FOLDER_NAME / "meta.json").read_text())["layout"] == LAYOUT_VERSION


@pytest.mark.parametrize("name", ["meta.json", "responses/zarr.json", "responses/c.0.0.0.0", "observed/zarr.json"])
@pytest.mark.parametrize("special", ["fifo", "dev-zero", "link-to-a-copy"])
def test_special_files_in_the_cache_are_never_opened(dataset, monkeypatch, name, special):
    open_dataset(dataset, radius=2)
    target = dataset / CACHE_FOLDER_NAME / name
    copy = dataset.parent / f"copy-{name.replace('/', '-')}"
    copy.write_bytes(target.read_bytes())
    target.unlink()
    if special == "fifo":
        os.mkfifo(target)  # opening it for reading without O_NONBLOCK would hang
    elif special == "dev-zero":
        os.symlink("/dev/zero", target)  # reading it would never end
    else:
        os.symlink(copy, target)  # identical content, but a link is never trusted
    reads = CountingReads(monkeypatch)
    open_dataset(dataset, radius=2)  # returns at all: a FIFO or /dev/zero opened would never end
    assert reads.count == 30
    assert (dataset / CACHE_FOLDER_NAME / name).is_file() and not (dataset / CACHE_FOLDER_NAME / name).is_symlink()


def write_uncompressed(path, image):
    """An uncompressed EXR: its size depends on the shape only, so two images share it."""
    with OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}) as exr:
        exr.write(str(path))


@pytest.mark.parametrize("how", ["replaced", "rewritten-in-place"])
def test_a_frame_swapped_for_one_of_the_same_size_and_mtime_rebuilds_the_cache(dataset, how):
    frame = dataset / "frames/00000.exr"
    write_uncompressed(frame, np.ones((6, 5, 3), np.float32))
    first = open_dataset(dataset, radius=2)
    assert first.impulse_image(0, 0)[0, 0, 0] == 1.0
    before = os.stat(frame)
    if how == "replaced":
        write_uncompressed(dataset / "new.exr", np.full((6, 5, 3), 7.0, np.float32))
        os.replace(dataset / "new.exr", frame)
    else:
        write_uncompressed(dataset / "new.exr", np.full((6, 5, 3), 7.0, np.float32))
        with open(frame, "r+b") as handle:
            handle.write((dataset / "new.exr").read_bytes())
    os.utime(frame, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert os.stat(frame).st_size == before.st_size and os.stat(frame).st_mtime_ns == before.st_mtime_ns
    assert open_dataset(dataset, radius=2).impulse_image(0, 0)[0, 0, 0] == 7.0


def test_a_cache_folder_linked_to_a_users_folder_never_touches_it(dataset, tmp_path, private_cache):
    precious = tmp_path / "thesis"
    precious.mkdir()
    (precious / "thesis.tex").write_text("precious")
    os.symlink(precious, dataset / CACHE_FOLDER_NAME)
    open_dataset(dataset, radius=2)
    open_dataset(dataset, radius=2)
    assert sorted(p.name for p in precious.iterdir()) == ["thesis.tex"]
    assert (precious / "thesis.tex").read_text() == "precious"
    assert (dataset / CACHE_FOLDER_NAME).is_symlink()
    assert any(private_cache.iterdir())  # the cache went to the user cache folder instead


# Paths ----------------------------------------------------------------------------------------

@pytest.fixture
def outside(tmp_path, dataset):
    """A folder beside the dataset holding copies of its frames."""
    folder = tmp_path / "elsewhere"
    folder.mkdir()
    for frame in (dataset / "frames").iterdir():
        (folder / frame.name).write_bytes(frame.read_bytes())
    return folder


def test_a_frame_linked_outside_the_dataset_is_refused_unless_allowed(dataset, outside):
    (dataset / "frames/00003.exr").unlink()
    os.symlink(outside / "00003.exr", dataset / "frames/00003.exr")
    refused(dataset, "frames/00003.exr: resolves to", "elsewhere/00003.exr, outside the dataset folder")
    assert open_dataset(dataset, allow_outside=True, use_cache=False).missing_count == 0


def test_a_frames_folder_linked_outside_the_dataset_is_refused(dataset, outside):
    for frame in (dataset / "frames").iterdir():
        frame.unlink()
    (dataset / "frames").rmdir()
    os.symlink(outside, dataset / "frames")
    refused(dataset, "frames/00000.exr: resolves to", "outside the dataset folder")
    open_dataset(dataset, allow_outside=True, use_cache=False)


def test_dark_and_mapping_linked_outside_the_dataset_are_refused(dataset, outside):
    write_rgb(outside / "dark.exr", np.zeros((6, 5, 3), np.float32))
    os.symlink(outside / "dark.exr", dataset / "dark.exr")
    edit_manifest(dataset, lambda m: m.update(dark="dark.exr"))
    refused(dataset, "dark.exr: resolves to", "outside the dataset folder")
    y, x = np.mgrid[:6, :5].astype(np.float32)
    write_exr(outside / "mapping.exr", {"y": y, "x": x})
    os.symlink(outside / "mapping.exr", dataset / "mapping.exr")
    edit_manifest(dataset, lambda m: (m.pop("dark"), m.update(frame_space="camera", mapping="mapping.exr")))
    refused(dataset, "mapping.exr: resolves to", "outside the dataset folder")


def test_a_link_inside_the_dataset_is_fine_and_a_link_loop_is_one_line(dataset):
    os.rename(dataset / "frames/00003.exr", dataset / "kept.exr")
    os.symlink(dataset / "kept.exr", dataset / "frames/00003.exr")
    open_dataset(dataset, use_cache=False)
    (dataset / "frames/00003.exr").unlink()
    os.symlink("00003.exr", dataset / "frames/00003.exr")  # points at itself
    refused(dataset, "frames/00003.exr")


# info's file check ----------------------------------------------------------------------------

def test_check_files_reports_every_broken_file_in_one_line_each(dataset):
    assert check_files(read_manifest(dataset)) == []
    path = dataset / "frames/00004.exr"
    path.write_bytes(path.read_bytes()[:-3])
    (dataset / "frames/00007.exr").unlink()
    write_rgb(dataset / "frames/00009.exr", np.zeros((6, 4, 3), np.float32))
    write_exr(dataset / "frames/00011.exr", {"Y": np.zeros((6, 5), np.float32)})
    (dataset / "frames/00012.exr").write_bytes(b"not an exr")
    problems = check_files(read_manifest(dataset))
    assert problems == [
        (f"{dataset}/frames/00004.exr: truncated or corrupt OpenEXR file (the file ends at byte "
         f"{path.stat().st_size}, before the end of its last chunk)"),
        f"{dataset}/frames/00007.exr: file not found",
        f"{dataset}/frames/00009.exr: frame is 6 x 4, expected 6 x 5 (the size of the grid)",
        f"{dataset}/frames/00011.exr: missing channel(s) R, G, B (found: Y)",
        f"{dataset}/frames/00012.exr: not an OpenEXR file",
    ]


def test_check_files_checks_frames_against_the_mapping_and_the_dark_frame(dataset):
    y, x = np.mgrid[:7, :5].astype(np.float32)
    write_exr(dataset / "mapping.exr", {"y": y, "x": x})
    write_rgb(dataset / "dark.exr", np.zeros((7, 5, 3), np.float32))
    edit_manifest(dataset, lambda m: m.update(frame_space="camera", mapping="mapping.exr", dark="dark.exr"))
    problems = check_files(read_manifest(dataset))
    assert len(problems) == 30
    assert problems[0] == f"{dataset}/frames/00000.exr: frame is 6 x 5, expected 7 x 5 (the size of the mapping)"
