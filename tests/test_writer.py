"""The dataset writer: round trip, atomicity, and never overwriting user data."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose
from reference import brute_ring_image, random_impulses
from ringlight.core import (
    DatasetError,
    DatasetWriter,
    open_dataset,
    read_exr_rgb,
    read_manifest,
    ring_stack,
)


def test_written_dataset_reads_back_with_every_key(tmp_path):
    rng = np.random.default_rng(0)
    impulses = random_impulses(rng, 10, 9, support=2)
    with DatasetWriter(tmp_path / "ds", (10, 9), max_radius=2, pitch_mm=0.1, notes="n") as writer:
        writer.add_frame(impulses[(1, 1)] + impulses[(6, 7)], lit=[[1, 1], [6, 7]], exposure=1.0)
        for q, image in impulses.items():
            if q not in ((1, 1), (6, 7)):
                writer.add_frame(image * 2, lit=[q], exposure=2.0)
        writer.set_dark(np.zeros((10, 9, 3), np.float32))
        writer.add_path_length_image(np.ones((10, 9, 3), np.float32), 0, 1)
        writer.set_layers([{"name": "top", "depth": [0, 2], "rgb": [0.8, 0.2, 0.1]}])
    manifest = read_manifest(tmp_path / "ds")
    assert (manifest.height, manifest.width, manifest.max_radius, manifest.pitch_mm) == (10, 9, 2.0, 0.1)
    assert manifest.ground_truth.layers[0].rgb == (0.8, 0.2, 0.1)
    assert manifest.ground_truth.path_length_images[0].max == 1.0
    stack = ring_stack(open_dataset(tmp_path / "ds"), [0, 1])
    assert_allclose(stack.images[1], brute_ring_image(impulses, 10, 9, 1), rtol=1e-5, atol=1e-7)
    assert_allclose(read_exr_rgb(tmp_path / "ds" / manifest.ground_truth.path_length_images[0].file), 1.0)


def test_an_error_inside_the_with_block_leaves_no_dataset(tmp_path):
    with pytest.raises(RuntimeError, match="camera unplugged"):
        with DatasetWriter(tmp_path / "ds", (4, 4)) as writer:
            writer.add_frame(np.zeros((4, 4, 3)), lit=[[0, 0]])
            raise RuntimeError("camera unplugged")
    assert list(tmp_path.iterdir()) == []


def test_an_invalid_dataset_is_never_published(tmp_path):
    with pytest.raises(DatasetError, match="outside the 4 x 4 grid") as refused:
        with DatasetWriter(tmp_path / "ds", (4, 4)) as writer:
            writer.add_frame(np.zeros((4, 4, 3)), lit=[[9, 0]])
    assert str(refused.value).startswith(f"{tmp_path / 'ds'}/dataset.json: ")  # never the hidden staging folder
    assert list(tmp_path.iterdir()) == []


def test_existing_user_folder_is_refused_and_a_dataset_replaced_only_on_request(tmp_path):
    from ringlight.core.atomic import OutputError

    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"x")
    with pytest.raises(OutputError, match="photos: exists and is not a ringlight dataset folder "
                                          r"\(it holds a.jpg\); refusing to overwrite it"):
        DatasetWriter(tmp_path / "photos", (2, 2), overwrite=True)
    for value in (1.0, 3.0):
        with DatasetWriter(tmp_path / "ds", (2, 2), overwrite=True) as writer:
            writer.add_frame(np.full((2, 2, 3), value), lit=[[0, 0]])
    assert read_exr_rgb(tmp_path / "ds/frames/000000.exr")[0, 0, 0] == 3.0
    with pytest.raises(OutputError, match="pass overwrite"):
        DatasetWriter(tmp_path / "ds", (2, 2))
    assert json.loads((tmp_path / "ds/dataset.json").read_text())["frames"][0]["lit"] == [[0, 0]]


def test_atomic_outputs_get_the_users_usual_permissions(tmp_path):
    import os

    from ringlight.core.atomic import atomic_file, atomic_folder

    umask = os.umask(0o022)
    try:
        with atomic_folder(tmp_path / "folder") as staging:
            (staging / "a").write_text("a")
        with atomic_file(tmp_path / "file.txt") as temporary:
            temporary.write_text("b")
    finally:
        os.umask(umask)
    assert (tmp_path / "folder").stat().st_mode & 0o777 == 0o755
    assert (tmp_path / "file.txt").stat().st_mode & 0o777 == 0o644
    assert sorted(path.name for path in tmp_path.iterdir()) == ["file.txt", "folder"]


def test_a_killed_simulations_staging_folder_is_swept_by_the_next_write(tmp_path, monkeypatch):
    """Issue 40, case 15: a killed ``simulate`` left ``.OUT.partial-HEX`` (160-424 KB) that nothing
    removed. The next write of that dataset removes a staging folder no process holds (older than
    ABANDONED_AGE, here 0), never one a writer holds nor a look-alike holding a user's file."""
    import os
    import signal
    import subprocess
    import sys

    from ringlight.core import staging_locks

    out = tmp_path / "ds"
    script = (
        "import os, signal, sys, numpy as np\n"
        "from ringlight.core import DatasetWriter\n"
        "with DatasetWriter(sys.argv[1], (4, 4)) as writer:\n"
        "    writer.add_frame(np.ones((4, 4, 3), np.float32), [[0, 0]])\n"
        "    os.kill(os.getpid(), signal.SIGKILL)\n")
    killed = subprocess.run([sys.executable, "-c", script, str(out)], capture_output=True)
    assert killed.returncode == -signal.SIGKILL
    abandoned = [path.name for path in tmp_path.iterdir() if path.name.startswith(".ds.partial-")]
    assert len(abandoned) == 1 and (tmp_path / abandoned[0] / "frames" / "000000.exr").is_file()
    users = tmp_path / ".ds.partial-abcdef012345"
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    held = tmp_path / ".ds.partial-0123456789ab"
    held.mkdir()
    lock = staging_locks.lock_staging(held)
    try:
        monkeypatch.setattr(staging_locks, "ABANDONED_AGE", 0.0)
        with DatasetWriter(out, (4, 4)) as writer:
            writer.add_frame(np.ones((4, 4, 3), np.float32), [[0, 0]])
    finally:
        os.close(lock)
    assert sorted(path.name for path in tmp_path.iterdir()) == [".ds.partial-0123456789ab",
                                                                 ".ds.partial-abcdef012345", "ds"]
