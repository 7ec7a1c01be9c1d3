"""Small scanline frames decoded from the bytes of their check (core/dataset/exr_small.py) hold
exactly what the OpenEXR library decodes from the same files, bit for bit, for every layout the
decoder takes; any other layout, and damaged chunks, are left to the library."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest
from ringlight.core import DatasetError
from ringlight.core.dataset import exr_small
from ringlight.core.dataset.exr import read_exr_channels
from ringlight.core.dataset.exr_seen import HeaderCache

COMPRESSIONS = {"none": OpenEXR.NO_COMPRESSION, "zips": OpenEXR.ZIPS_COMPRESSION, "zip": OpenEXR.ZIP_COMPRESSION,
                "rle": OpenEXR.RLE_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION}


def write(path, planes, compression):
    header = {"compression": COMPRESSIONS[compression], "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {name: np.ascontiguousarray(plane) for name, plane in planes.items()}) as exr:
        exr.write(str(path))


def planes_of(rng, names, shape, dtype, kind):
    """Random values (with NaN, Inf, -0 and subnormals), smooth ones (which ZIP packs), or a constant."""
    planes = {}
    for name in names:
        if kind == "random":
            plane = rng.normal(0, 100, shape).astype(dtype)
            plane.flat[rng.integers(0, plane.size, 3)] = [np.nan, np.inf, -0.0]
            plane.flat[0] = np.finfo(dtype).tiny / 4
        elif kind == "smooth":
            plane = (np.add.outer(np.arange(shape[0]), np.arange(shape[1])) * 0.01).astype(dtype)
        else:
            plane = np.full(shape, 0.25, dtype)
        planes[name] = plane
    return planes


def decode_in_run(path, names, rows=None):
    """The compiled decode of a run of frames (exr_small._decode_frame) of ``rows`` of the file,
    or None when it hands the file back to be read alone."""
    from ringlight.core.dataset.exr_chunks import chunk_layout

    data = path.read_bytes()
    with open(path, "rb") as handle:
        chunks, _ = chunk_layout(handle, data, len(data))
    small = exr_small.small_layout(data[:chunks.table_start])
    first, stop = rows if rows is not None else (0, small.height)
    image = np.full((stop - first, small.width, len(names)), np.nan, np.float32)
    decoded = exr_small._decode_frame(np.frombuffer(data, np.uint8), 0, len(data),
                                      exr_small.layout_array(small, chunks.table_start, first), small.width,
                                      *exr_small._picked(small, tuple(names)), exr_small._HALF_TO_FLOAT, image,
                                      np.zeros(2, exr_small.LENGTH_TYPE),
                                      np.empty(small.lines * small.line_bytes, np.uint8))
    return image if decoded else None


def read_both(path, names, monkeypatch, rows=None):
    """(the library's decode, this module's decode, whether this module decoded it) of ``rows``."""
    library = read_exr_channels(path, names, rows=rows)
    taken = []
    original = exr_small.decode_small
    monkeypatch.setattr("ringlight.core.dataset.exr.decode_small", lambda *args: (
        lambda decoded: (taken.append(decoded), decoded)[1])(original(*args)))
    ours = read_exr_channels(path, names, rows=rows, headers=HeaderCache())
    monkeypatch.undo()
    return library, ours, bool(taken and taken[0])


@pytest.mark.parametrize("compression", ["none", "zips", "zip"])
@pytest.mark.parametrize("dtype", [np.float16, np.float32])
@pytest.mark.parametrize("shape", [(1, 1), (3, 17), (40, 33), (100, 7)])
@pytest.mark.parametrize("kind", ["random", "smooth", "constant"])
def test_small_frames_decode_bit_for_bit_as_the_library_does(tmp_path, monkeypatch, compression, dtype, shape, kind):
    rng = np.random.default_rng(hash((compression, shape, kind)) % 2**32)
    names = ("A", "B", "G", "R", "camera.Z")  # extra channels around the ones read
    path = tmp_path / "frame.exr"
    write(path, planes_of(rng, names, shape, dtype, kind), compression)
    for wanted in (("R", "G", "B"), ("camera.Z",), ("B", "A")):
        library, ours, taken = read_both(path, wanted, monkeypatch)
        assert taken
        assert ours.dtype == library.dtype == np.float32 and ours.shape == library.shape == (*shape, len(wanted))
        assert ours.view(np.uint32).tobytes() == library.view(np.uint32).tobytes()  # NaN payloads too
        assert decode_in_run(path, wanted).view(np.uint32).tobytes() == library.view(np.uint32).tobytes()
    if shape[0] > 2:  # a band of rows, across chunks of 16 lines in ZIP
        rows = (shape[0] // 3, shape[0] - shape[0] // 4)
        library, ours, taken = read_both(path, ("R", "G", "B"), monkeypatch, rows)
        assert taken and ours.view(np.uint32).tobytes() == library.view(np.uint32).tobytes()
        assert decode_in_run(path, ("R", "G", "B"), rows).view(np.uint32).tobytes() == library.view(np.uint32).tobytes()


@pytest.mark.parametrize("compression", ["rle", "piz"])
def test_other_compressions_and_uint_channels_are_left_to_the_library(tmp_path, monkeypatch, compression):
    path = tmp_path / "frame.exr"
    write(path, planes_of(np.random.default_rng(1), ("R", "G", "B"), (9, 8), np.float32, "random"), compression)
    library, ours, taken = read_both(path, ("R", "G", "B"), monkeypatch)
    assert not taken and ours.view(np.uint32).tobytes() == library.view(np.uint32).tobytes()
    write(path, {"R": np.arange(72, dtype=np.uint32).reshape(9, 8), "G": np.ones((9, 8), np.float32),
                 "B": np.ones((9, 8), np.float32)}, "zip")
    library, ours, taken = read_both(path, ("R", "G", "B"), monkeypatch)
    assert not taken and np.array_equal(ours, library) and ours[8, 7, 0] == 71


def test_a_damaged_chunk_is_left_to_the_library_which_names_the_file(tmp_path):
    """A flipped byte inside a ZIP chunk's data: zlib refuses it here, and the library's own
    error is the one line (the chunk table still fits the file, so the check passes)."""
    path = tmp_path / "frame.exr"
    write(path, planes_of(np.random.default_rng(2), ("R", "G", "B"), (40, 33), np.float16, "smooth"), "zip")
    data = bytearray(path.read_bytes())
    data[-40] ^= 0xFF
    path.write_bytes(bytes(data))
    assert decode_in_run(path, ("R", "G", "B")) is None  # the compiled decode of a run hands it back too
    with pytest.raises(DatasetError, match="frame.exr: truncated or corrupt OpenEXR file"):
        read_exr_channels(path, ("R", "G", "B"), headers=HeaderCache())


@pytest.mark.parametrize("cut", [1, 8, 20])
def test_a_run_hands_back_a_frame_whose_chunk_table_does_not_fit(tmp_path, cut):
    """A frame cut short (its last chunk, its chunk's header) fails the compiled table check, as
    exr_chunks.offsets_problem says of it, and is handed back to be read alone."""
    from ringlight.core.dataset.exr_chunks import chunk_layout, offsets_problem

    path = tmp_path / "frame.exr"
    write(path, planes_of(np.random.default_rng(3), ("R", "G", "B"), (20, 9), np.float16, "smooth"), "zip")
    assert decode_in_run(path, ("R", "G", "B")) is not None
    data = path.read_bytes()[:-cut]
    with open(path, "rb") as handle:
        chunks, head = chunk_layout(handle, path.read_bytes(), len(data) + cut)
    path.write_bytes(data)
    with open(path, "rb") as handle:
        assert offsets_problem(handle, data, len(data), chunks) is not None
    assert decode_in_run(path, ("R", "G", "B")) is None
