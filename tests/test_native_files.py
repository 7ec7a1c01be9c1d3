"""The system calls of a long manifest's open made from compiled code (core/dataset/native_files.py)
give what Python's calls gave, file for file, and visit each file once: checked against the same
runs read with Python's calls (the code before), against ``os.stat``, and, where strace is
installed, by counting the system calls themselves."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from reference import write_rgb
from ringlight.core.dataset import cache, file_batch
from ringlight.core.dataset.exr_chunks import HEAD_BYTES
from ringlight.core.dataset.file_paths import FileResolver
from ringlight.core.dataset.native_files import NATIVE_FILES

pytestmark = pytest.mark.skipif(not NATIVE_FILES, reason="no statx here: files are visited from Python")


def mixed_folder(root: Path) -> tuple[Path, list[str], bytes]:
    """A dataset folder whose frames are every kind of file a run meets, and the header its small
    frames share."""
    folder = root / "ds"
    (folder / "frames").mkdir(parents=True)
    write_rgb(folder / "frames" / "a.exr", np.full((10, 10, 3), 0.5, np.float32), half=True)
    write_rgb(folder / "frames" / "b.exr", np.full((10, 10, 3), 2.0, np.float32), half=True)
    write_rgb(folder / "frames" / "wide.exr", np.ones((10, 11, 3), np.float32), half=True)  # another header
    (folder / "frames" / "big.exr").write_bytes((folder / "frames" / "a.exr").read_bytes() + bytes(HEAD_BYTES))
    (folder / "frames" / "link.exr").symlink_to("b.exr")  # a link inside: resolved from Python
    os.mkfifo(folder / "frames" / "fifo.exr")
    outside = root / "elsewhere"
    outside.mkdir()
    write_rgb(outside / "c.exr", np.ones((10, 10, 3), np.float32), half=True)
    (folder / "away").symlink_to(outside, target_is_directory=True)  # a folder outside
    (folder / "top.exr").write_bytes((folder / "frames" / "b.exr").read_bytes())
    header = (folder / "frames" / "a.exr").read_bytes()[:300]
    names = ["frames/a.exr", "frames/big.exr", "frames/b.exr", "frames/wide.exr", "frames/link.exr", "top.exr",
             "frames/a.exr"]
    return folder, names, header


def runs_of(folder: Path, names: list[str], header: bytes, monkeypatch, allow_outside: bool = False):
    """The run of ``names`` read with the compiled calls, then with Python's alone (the reference)."""
    compiled = file_batch.read_run(FileResolver(folder, allow_outside), names, header)
    with monkeypatch.context() as patch:
        patch.setattr(file_batch, "NATIVE_FILES", False)
        python = file_batch.read_run(FileResolver(folder, allow_outside), names, header)
    return compiled, python


def assert_same_run(compiled, python) -> None:
    """The same bytes of each file read whole (the files visited from Python come after the others
    in the compiled call's buffer), sizes, identities and errors."""
    assert compiled.sizes.tolist() == python.sizes.tolist()
    for start, other, size in zip(compiled.starts.tolist(), python.starts.tolist(), compiled.sizes.tolist()):
        assert compiled.data[start:start + max(size, 0)].tobytes() == python.data[other:other + max(size, 0)].tobytes()
    assert len(compiled.data) == len(python.data)
    assert compiled.identities.tolist() == python.identities.tolist()
    assert {at: str(error) for at, error in compiled.errors.items()} == \
        {at: str(error) for at, error in python.errors.items()}


@pytest.mark.parametrize("last", [None, "frames/missing.exr", "frames/fifo.exr", "away/c.exr"])
def test_a_run_read_from_compiled_code_is_the_run_read_with_pythons_calls(tmp_path, monkeypatch, last):
    """Small files of the header read whole, the big one and the one of another header marked to
    read alone, the link inside read from Python; a file that cannot be read is said in Python's
    words (missing, not a file, in a folder outside) in its place, and the run goes on."""
    folder, names, header = mixed_folder(tmp_path)
    listed = names + ([last] if last else []) + ["frames/b.exr"]
    compiled, python = runs_of(folder, listed, header, monkeypatch)
    assert_same_run(compiled, python)
    whole = {"frames/a.exr", "frames/b.exr", "frames/link.exr", "top.exr"}
    assert compiled.sizes.tolist() == [os.stat(folder / name).st_size if name in whole else -1 for name in listed]
    identities = [list(cache.file_identity(os.stat(folder / name))) if name != last else [-1] * 4 for name in listed]
    assert compiled.identities.tolist() == identities
    expected = {"frames/missing.exr": f"{folder}/frames/missing.exr: file not found",
                "frames/fifo.exr": f"{folder}/frames/fifo.exr: not a file",
                "away/c.exr": f"{folder}/away/c.exr: resolves to {tmp_path}/elsewhere/c.exr, outside the dataset "
                              f"folder {folder}; allow files outside it explicitly (--allow-outside) to read it"}
    assert {at: str(error) for at, error in compiled.errors.items()} == ({len(names): expected[last]} if last else {})


def test_files_outside_the_folder_are_read_when_allowed(tmp_path, monkeypatch):
    folder, names, header = mixed_folder(tmp_path)
    compiled, python = runs_of(folder, ["away/c.exr", "frames/link.exr", "frames/a.exr"], header, monkeypatch,
                               allow_outside=True)
    assert_same_run(compiled, python)
    assert compiled.errors == {} and (compiled.sizes >= 0).all()


def test_a_reopens_identities_from_compiled_code_are_those_of_os_stat(tmp_path, monkeypatch):
    """Links followed, a missing file -1, as ``os.stat`` gives them (the key of the store)."""
    folder, names, _ = mixed_folder(tmp_path)
    names = names + ["away/c.exr", "frames/missing.exr", "frames/fifo.exr"]
    compiled = cache._identities(folder, names)
    with monkeypatch.context() as patch:
        patch.setattr(cache, "NATIVE_FILES", False)
        python = cache._identities(folder, names)
    assert compiled.tolist() == python.tolist()
    assert compiled[1].tolist() == list(cache.file_identity(os.stat(folder / "frames" / "big.exr")))
    assert compiled[-2].tolist() == [-1] * 4


STRACED = """
import os, sys
from ringlight.core import load_manifest, open_dataset
from ringlight.core.dataset.checks import check_files
manifest = load_manifest(sys.argv[1])
os.path.exists("/ringlight-phase-check")  # a mark in the log
assert check_files(manifest) == []
os.path.exists("/ringlight-phase-open")  # a mark in the log
open_dataset(manifest)
os.path.exists("/ringlight-phase-reopen")  # a mark in the log
open_dataset(manifest)
"""


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_each_frame_file_is_visited_once_by_the_system_calls_themselves(tmp_path):
    """Counted by strace: ``info``'s check opens each frame once and stats none by name; a first
    open likewise; a reopen stats each frame once by name and opens none. Frame 0 is visited
    alone (its channels, its header by the library, the first frame's checks) a few times more."""
    folder = tmp_path / "ds"
    (folder / "frames").mkdir(parents=True)
    write_rgb(folder / "frames" / "base.exr", np.ones((10, 10, 3), np.float32), half=True)
    frames = []
    for index in range(300):
        os.link(folder / "frames" / "base.exr", folder / "frames" / f"{index:06d}.exr")
        frames.append({"file": f"frames/{index:06d}.exr", "lit": [[(index // 10) % 10, index % 10]]})
    (folder / "dataset.json").write_text(json.dumps({"format": "ringlight-impulse", "version": 1, "max_radius": 2,
                                                     "grid": {"height": 10, "width": 10}, "frames": frames}))
    log = tmp_path / "calls.log"
    traced = subprocess.run(["strace", "-f", "--seccomp-bpf", "-qq", "-o", str(log), "-e",
                             "trace=open,openat,stat,lstat,newfstatat,statx", sys.executable, "-c", STRACED,
                             str(folder)], capture_output=True, text=True, timeout=120)
    if traced.returncode != 0 and "Traceback" not in traced.stderr:  # no ptrace, no --seccomp-bpf (strace < 5.3)
        pytest.skip(f"strace cannot trace here: {traced.stderr.strip()[:200]}")
    assert traced.returncode == 0, traced.stderr
    phases, phase = {}, None
    for line in log.read_text().splitlines():
        call = line.split(None, 1)[1] if " " in line else line
        if "/ringlight-phase-" in call:
            phase = call.split("/ringlight-phase-")[1].split('"')[0]
            phases[phase] = {"opened": [], "stated": []}
            continue
        if phase is None or "frames/0" not in call or " = -1 " in call:
            continue
        name = call.split('"')[1].rsplit("/", 1)[1]
        phases[phase]["opened" if call.startswith("open") else "stated"].append(name)
    every = sorted(f"{index:06d}.exr" for index in range(1, 300))
    for step in ("check", "open"):
        opened = [name for name in phases[step]["opened"] if name != "000000.exr"]
        assert sorted(opened) == every, step
        assert [name for name in phases[step]["stated"] if name != "000000.exr"] == [], step
        assert phases[step]["opened"].count("000000.exr") <= 8, step  # 5 and 6 here, the library's opens with them
    assert sorted(phases["reopen"]["stated"]) == ["000000.exr"] + every and phases["reopen"]["opened"] == []


def test_files_handed_back_do_not_split_the_compiled_call(tmp_path, monkeypatch):
    """A run of frames that are links inside the folder (each opened from Python, as a link must
    be resolved) takes one compiled call, not one a link, and the rest of the run stays in it."""
    folder, _, header = mixed_folder(tmp_path)
    calls = []
    original = file_batch.read_files
    monkeypatch.setattr(file_batch, "read_files", lambda *args: (calls.append(1), original(*args))[1])
    run = file_batch.read_run(FileResolver(folder), ["frames/link.exr", "frames/a.exr"] * 50, header)
    assert calls == [1] and run.errors == {} and (run.sizes > 0).all()
    assert len(run.data) == 50 * (os.stat(folder / "frames/a.exr").st_size + os.stat(folder / "frames/b.exr").st_size)
