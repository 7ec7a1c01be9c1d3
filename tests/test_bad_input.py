"""Every bad input of the core issue gives one line naming the file and the problem, exit 2."""

import subprocess
import sys
import warnings

import numpy as np
import pytest
from reference import (
    edit_manifest,
    random_impulses,
    write_dataset,
    write_exr,
    write_rgb,
)
from ringlight.app.main import main


@pytest.fixture
def dataset(tmp_path):
    """A valid 6 x 5 one-point-per-frame dataset; tests break one thing each."""
    impulses = random_impulses(np.random.default_rng(0), 6, 5, support=10)
    write_dataset(tmp_path / "ds", 6, 5, impulses)
    return tmp_path / "ds"


def run_cli(capsys, *args):
    status = main(list(map(str, args)))
    captured = capsys.readouterr()
    return status, captured.err


def assert_one_line_error(capsys, folder, *needles, command="stack"):
    extra = ["--radii", "0:2:1", "--out", folder.parent / "out"] if command == "stack" else []
    status, err = run_cli(capsys, command, folder, *extra)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("ringlight: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_missing_manifest(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert_one_line_error(capsys, tmp_path / "empty", "empty/dataset.json", "manifest not found")


def test_a_file_given_as_the_dataset_is_named_as_a_file(tmp_path, capsys):
    """``ringlight info notes.txt`` said "notes.txt/dataset.json: manifest not found"."""
    (tmp_path / "notes.txt").write_text("mine")
    line = assert_one_line_error(capsys, tmp_path / "notes.txt", command="info")
    assert line == f"ringlight: error: {tmp_path / 'notes.txt'}: is a file, not a dataset folder or its dataset.json"


def test_empty_radii_are_refused_not_taken_for_auto(dataset, capsys):
    status, err = run_cli(capsys, "layers", dataset, "--radii", "")
    assert status == 2 and err.strip() == ("ringlight: error: --radii '' must be numbers separated by commas, "
                                           "e.g. 2,5,8")


def test_missing_folder(tmp_path, capsys):
    assert_one_line_error(capsys, tmp_path / "nowhere", "nowhere", "no such dataset folder", command="info")


def test_invalid_json(dataset, capsys):
    (dataset / "dataset.json").write_text("{ not json")
    assert_one_line_error(capsys, dataset, "dataset.json", "invalid JSON at line 1")


def test_wrong_format(dataset, capsys):
    edit_manifest(dataset, lambda m: m.update(format="something-else"))
    assert_one_line_error(capsys, dataset, "dataset.json", "'format' is 'something-else'", command="info")


def test_wrong_version(dataset, capsys):
    edit_manifest(dataset, lambda m: m.update(version=2))
    assert_one_line_error(capsys, dataset, "dataset.json", "unsupported 'version' 2")


@pytest.mark.parametrize(
    "change, needle",
    [
        (lambda m: m["grid"].update(height="6"), "'grid.height' must be a positive integer, got '6'"),
        (lambda m: m.update(frames={}), "'frames' must be a list"),
        (lambda m: m["frames"][0].update(exposure=-1), "'frames[0].exposure' must be a positive number"),
        (lambda m: m.update(max_radius=True), "'max_radius' must be a finite number"),
        (lambda m: m["frames"][1].update(lit=[[0.5, 1]]), "frames[1].lit[0] must be [y, x] integers"),
        (lambda m: m.update(colorspace="not-a-space"), "'colorspace' 'not-a-space' is not a colour-science"),
        (lambda m: m.update(max_raduis=3), "unknown key(s) 'max_raduis' in manifest"),
        (lambda m: m["frames"][0].update(file="../outside.exr"), "a relative path inside the dataset folder"),
        (lambda m: m.update(frame_space="camera"), "needs a 'mapping' file"),
    ],
)
def test_keys_of_the_wrong_type_or_unknown_keys(dataset, capsys, change, needle):
    edit_manifest(dataset, change)
    assert_one_line_error(capsys, dataset, "dataset.json", needle, command="info")


def test_missing_frame(dataset, capsys):
    (dataset / "frames/00003.exr").unlink()
    assert_one_line_error(capsys, dataset, "frames/00003.exr", "file not found")


def test_frame_that_is_a_folder_cannot_be_read(dataset, capsys):
    (dataset / "frames/00003.exr").unlink()
    (dataset / "frames/00003.exr").mkdir()
    assert_one_line_error(capsys, dataset, "frames/00003.exr", "not a file")


def test_truncated_frame(dataset, capsys):
    path = dataset / "frames/00004.exr"
    write_rgb(path, np.random.default_rng(1).random((6, 5, 3)).astype(np.float32))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    assert_one_line_error(capsys, dataset, "frames/00004.exr", "truncated or corrupt")


def test_non_exr_frame(dataset, capsys):
    (dataset / "frames/00002.exr").write_bytes(b"\x89PNG\r\n\x1a\n not an exr at all")
    assert_one_line_error(capsys, dataset, "frames/00002.exr", "not an OpenEXR file")


def test_frame_of_the_wrong_size(dataset, capsys):
    write_rgb(dataset / "frames/00001.exr", np.zeros((6, 4, 3), np.float32))
    assert_one_line_error(capsys, dataset, "frames/00001.exr", "frame is 6 x 4, expected 6 x 5")


def test_dark_frame_of_the_wrong_size(dataset, capsys):
    write_rgb(dataset / "dark.exr", np.zeros((5, 5, 3), np.float32))
    edit_manifest(dataset, lambda m: m.update(dark="dark.exr"))
    assert_one_line_error(capsys, dataset, "dark.exr", "dark frame is 5 x 5, expected 6 x 5")


def test_mapping_of_a_different_size_than_the_frames(dataset, capsys):
    y, x = np.mgrid[:7, :5].astype(np.float32)
    write_exr(dataset / "mapping.exr", {"y": y, "x": x})
    edit_manifest(dataset, lambda m: m.update(frame_space="camera", mapping="mapping.exr"))
    assert_one_line_error(capsys, dataset, "frames/00000.exr", "frame is 6 x 5, expected 7 x 5 (the size of the mapping)")


def test_mapping_without_y_and_x_channels(dataset, capsys):
    write_rgb(dataset / "mapping.exr", np.zeros((6, 5, 3), np.float32))
    edit_manifest(dataset, lambda m: m.update(frame_space="camera", mapping="mapping.exr"))
    assert_one_line_error(capsys, dataset, "mapping.exr", "missing channel(s) y, x")


def test_frame_without_rgb_channels(dataset, capsys):
    write_exr(dataset / "frames/00005.exr", {"Y": np.zeros((6, 5), np.float32)})
    assert_one_line_error(capsys, dataset, "frames/00005.exr", "missing channel(s) R, G, B (found: Y)")


def test_lit_point_outside_the_grid(dataset, capsys):
    edit_manifest(dataset, lambda m: m["frames"][2].update(lit=[[6, 0]]))
    assert_one_line_error(capsys, dataset, "dataset.json", "frames[2] (frames/00002.exr) lights [6, 0], outside the 6 x 5 grid")


def test_multiplexed_points_too_close(dataset, capsys):
    edit_manifest(dataset, lambda m: (m.update(max_radius=1.5), m["frames"][0].update(lit=[[0, 0], [3, 0]])))
    assert_one_line_error(capsys, dataset, "frames[0] (frames/00000.exr) lights [0, 0] and [3, 0] 3 apart", "more than 2 * max_radius = 3 apart")


def test_multiplexed_frames_without_max_radius(dataset, capsys):
    edit_manifest(dataset, lambda m: m["frames"][0].update(lit=[[0, 0], [5, 4]]))
    assert_one_line_error(capsys, dataset, "dataset.json", "'max_radius' is required")


def test_nan_and_inf_radiance_are_counted_with_the_first_file(dataset, capsys):
    image = np.ones((6, 5, 3), np.float32)
    image[0, 0, 0] = np.nan
    image[1, 1] = np.inf
    write_rgb(dataset / "frames/00007.exr", image)
    image = np.ones((6, 5, 3), np.float32)
    image[2, 2, 1] = -np.inf
    write_rgb(dataset / "frames/00011.exr", image)
    assert_one_line_error(capsys, dataset, "frames/00007.exr", "NaN or Inf radiance (5 values in 2 frame(s)")


def test_output_folder_that_is_not_a_stack_is_never_overwritten(dataset, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    line = assert_one_line_error(capsys, dataset, "out", "exists and is not a ringlight stack folder")
    assert (out / "thesis.tex").read_text() == "precious"
    assert "refusing to overwrite" in line


def test_bad_radii_argument(dataset, capsys):
    status, err = run_cli(capsys, "stack", dataset, "--radii", "1-5", "--out", dataset.parent / "o")
    assert status == 2 and "radii '1-5' must be START:STOP:STEP" in err


def test_the_installed_command_prints_no_traceback(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "ringlight.app", "info", str(tmp_path / "absent")],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"ringlight: error: {tmp_path / 'absent'}: no such dataset folder"


@pytest.mark.parametrize("radii", ["1e308:1e308:1", "0:1e300:1e296"])
def test_radii_too_large_to_hold_are_one_line_without_a_warning(dataset, capsys, radii):
    """1e308:1e308:1 overflowed in the radii's rounding (numpy's RuntimeWarning on the terminal) and
    was refused as not finite, though every number given was."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        status, err = run_cli(capsys, "stack", dataset, "--radii", radii, "--out", dataset.parent / "o")
    stop = radii.split(":")[1]
    assert status == 2 and err.strip() == (f"ringlight: error: ring radius {float(stop):g} reaches beyond 4096 grid "
                                           "steps, more than any dataset holds")
