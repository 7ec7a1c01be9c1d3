"""The store's copy of the manifest: a reopen reads it instead of the JSON, and only when it was
made from the same bytes and passes the checks again."""

import dataclasses
import hashlib
import io
import json
import zipfile

import numpy as np
import pytest
import ringlight.core.dataset.manifest_copy as copy_module
from numpy.testing import assert_array_equal
from reference import random_impulses, write_dataset
from ringlight.core import load_manifest, open_dataset, read_manifest
from ringlight.core.dataset.cache import cache_location
from ringlight.core.dataset.manifest_copy import COPY_NAME

EXTRA = {"grid": {"height": 9, "width": 8, "pitch_mm": 0.25}, "colorspace": "sRGB", "notes": "two layers",
         "ground_truth": {"layers": [{"name": "top", "depth": [0, 1.5], "rgb": [0.8, 0.2, 0.1]}]}}


@pytest.fixture
def dataset(tmp_path):
    impulses = random_impulses(np.random.default_rng(3), 9, 8, support=3)
    write_dataset(tmp_path / "ds", 9, 8, impulses, max_radius=2.0, multiplex=True, extra=EXTRA)
    return tmp_path / "ds"


def assert_same_manifest(loaded, parsed):
    for field in dataclasses.fields(parsed):
        if field.name != "frames":
            assert getattr(loaded, field.name) == getattr(parsed, field.name), field.name
    assert len(loaded.frames) == len(parsed.frames) > 1
    for ours, theirs in zip(loaded.frames, parsed.frames):
        assert (ours.file, ours.exposure) == (theirs.file, theirs.exposure)
        assert ours.lit.dtype == theirs.lit.dtype == np.int64
        assert_array_equal(ours.lit, theirs.lit)


def no_json(monkeypatch):
    """Make decoding the manifest's JSON fail, to prove a load did not do it."""
    def refuse(*args, **kwargs):
        raise AssertionError("the manifest's JSON was decoded")

    monkeypatch.setattr(copy_module, "decode_json", refuse)


def test_a_reopen_reads_the_stores_copy_and_it_equals_the_parsed_manifest(dataset, monkeypatch):
    parsed = read_manifest(dataset)
    assert parsed.multiplexed and parsed.ground_truth.layers and parsed.pitch_mm == 0.25
    first = open_dataset(dataset)
    assert (cache_location(dataset) / COPY_NAME).is_file()
    no_json(monkeypatch)
    loaded = load_manifest(dataset)
    assert_same_manifest(loaded, parsed)
    again = open_dataset(dataset)  # from the copy and the store: no JSON, no frame decoded
    assert again.store is not None
    assert_array_equal(again.responses, first.responses)


@pytest.mark.parametrize("colorspace", [
    "ACEScg",
    {"matrix": [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]},
    {"primaries": [[0.68, 0.32], [0.265, 0.69], [0.15, 0.06]], "whitepoint": [0.3127, 0.329]},
])
def test_every_kind_of_colourspace_is_kept_in_the_copy(tmp_path, monkeypatch, colorspace):
    folder = tmp_path / "ds"
    impulses = random_impulses(np.random.default_rng(7), 6, 5, support=2)
    write_dataset(folder, 6, 5, impulses, extra={"colorspace": colorspace, "channels": ["R", "G", "B"]})
    parsed = read_manifest(folder)
    open_dataset(folder)
    no_json(monkeypatch)
    assert_same_manifest(load_manifest(folder), parsed)


def test_an_edited_manifest_is_parsed_again(dataset):
    open_dataset(dataset)
    document = json.loads((dataset / "dataset.json").read_text())
    document["notes"] = "edited after the store was written"
    (dataset / "dataset.json").write_text(json.dumps(document))
    assert load_manifest(dataset).notes == "edited after the store was written"


def retable(entry, relative):
    """Record the file's present size and SHA-256 in the store's table, as an edit made knowing
    the table would: the copy's own checks must then refuse it."""
    meta = json.loads((entry / "meta.json").read_text())
    data = (entry / relative).read_bytes()
    meta["table"][relative] = [len(data), hashlib.sha256(data).hexdigest()]
    (entry / "meta.json").write_text(json.dumps(meta))


def npy_claiming(shape):
    """The bytes of an .npy file of int64 whose header claims ``shape`` but holds 16 bytes."""
    header = repr({"descr": "<i8", "fortran_order": False, "shape": shape}).encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + bytes(16)


@pytest.mark.parametrize("damage", ["lit outside the grid", "file outside the folder", "counts", "garbage",
                                    "another digest", "a link", "a huge header", "counts that wrap",
                                    "exposures edited, table not"])
def test_a_copy_that_fails_a_check_is_ignored(dataset, monkeypatch, damage):
    open_dataset(dataset)
    entry = cache_location(dataset)
    path = entry / COPY_NAME
    with np.load(path) as stored:
        arrays = dict(stored)
    if damage == "lit outside the grid":
        arrays["lit"][3] = [9, 0]  # row 9 of a 9-row grid
    elif damage == "file outside the folder":
        arrays["files"] = np.array(["../elsewhere.exr", *arrays["files"][1:].tolist()])
    elif damage == "counts":
        arrays["counts"][0] += 1
    elif damage == "counts that wrap":  # each positive, their int64 sum still the points' count
        arrays["counts"][:4] += 2**62
    elif damage == "another digest":
        arrays["digest"] = np.str_("0" * 64)
    elif damage == "exposures edited, table not":
        arrays["exposures"] = arrays["exposures"] * 2
    if damage == "garbage":
        path.write_bytes(b"PK\x03\x04 not a zip")
    elif damage == "a link":  # the very copy, moved out of the store and linked in: never followed
        path.rename(dataset / "moved.npz")
        path.symlink_to(dataset / "moved.npz")
    elif damage == "a huge header":  # 10^12 lit points claimed: never allocated
        with zipfile.ZipFile(path, "w") as archive:
            for name, array in arrays.items():
                if name == "lit":
                    archive.writestr("lit.npy", npy_claiming((10**12, 2)))
                else:
                    buffer = io.BytesIO()
                    np.save(buffer, array)
                    archive.writestr(f"{name}.npy", buffer.getvalue())
    else:
        np.savez(path, **arrays)
    if damage not in ("a link", "exposures edited, table not"):
        retable(entry, COPY_NAME)
    calls = []
    monkeypatch.setattr(copy_module, "decode_json", lambda *args, **kwargs: calls.append(1) or json.loads(args[0]))
    assert_same_manifest(load_manifest(dataset), read_manifest(dataset))
    assert calls == [1]  # parsed, not taken from the copy


def test_a_manifest_built_in_memory_leaves_no_copy(dataset):
    manifest = dataclasses.replace(read_manifest(dataset), source_sha256=None)
    open_dataset(manifest)
    assert cache_location(dataset).is_dir() and not (cache_location(dataset) / COPY_NAME).exists()
