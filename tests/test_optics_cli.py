"""``ringlight optics`` on a homogeneous dataset written as frames (the maps' model response with
2 % noise per response value, pitch 0.1 mm): maps as named EXR channels, the region's JSON,
calibration, and one-line refusals."""

import dataclasses
import json
import re

import numpy as np
import OpenEXR
import pytest
from optics_helpers import TEST_PHOTONS, model_kernel
from reference import write_dataset
from ringlight.app.main import main
from ringlight.core.dataset.exr import read_exr_channels
from ringlight.core.optics import radial

MUA, MUSP = 0.2, 5.0  # per mm: 0.02 and 0.5 per grid step of 0.1 mm
SIZE, MAX_RADIUS = 26, 6
PHOTONS = ["--photons", str(TEST_PHOTONS)]


@pytest.fixture(scope="module")
def homogeneous(tmp_path_factory):
    """The dataset's folder: every point lit in frames of 4 points (a lattice 13 apart)."""
    run = radial.run_radial(1.4, 0.0, TEST_PHOTONS, seed=0)  # the seed the command's table uses
    kernel = model_kernel(run, MUSP * 0.1, MUA * 0.1, MAX_RADIUS)
    rng = np.random.default_rng(5)
    impulses = {}
    for y in range(SIZE):
        for x in range(SIZE):
            image = np.zeros((SIZE, SIZE, 3), np.float32)
            y0, y1, x0, x1 = max(0, y - MAX_RADIUS), min(SIZE, y + MAX_RADIUS + 1), max(0, x - MAX_RADIUS), \
                min(SIZE, x + MAX_RADIUS + 1)
            window = kernel[y0 - y + MAX_RADIUS:y1 - y + MAX_RADIUS, x0 - x + MAX_RADIUS:x1 - x + MAX_RADIUS]
            image[y0:y1, x0:x1] = window * (1 + 0.02 * rng.standard_normal(window.shape))
            yy, xx = np.mgrid[:SIZE, :SIZE]
            image[np.hypot(yy - y, xx - x) > MAX_RADIUS] = 0.0
            impulses[(y, x)] = image
    folder = tmp_path_factory.mktemp("optics") / "homogeneous"
    write_dataset(folder, SIZE, SIZE, impulses, max_radius=MAX_RADIUS, multiplex=True,
                  extra={"grid": {"height": SIZE, "width": SIZE, "pitch_mm": 0.1}, "sample": {"n": 1.4}})
    return str(folder)


def test_optics_writes_maps_and_the_regions_values(homogeneous, tmp_path, capsys):
    out, document = tmp_path / "maps.exr", tmp_path / "region.json"
    assert main(["optics", homogeneous, "--out", str(out), "--json", str(document), "--mtf", "0,0.5,1.",
                 *PHOTONS]) == 0
    names = tuple(f"{p}.{c}{s}" for p in ("mua", "musp") for c in "RGB" for s in ("", "_se"))
    maps = read_exr_channels(out, names)
    centre = maps[13, 13].reshape(2, 3, 2)  # (property, channel, value / se)
    np.testing.assert_allclose(centre[0, :, 0], MUA, rtol=4 * centre[0, :, 1].max() / MUA)
    np.testing.assert_allclose(centre[1, :, 0], MUSP, rtol=4 * centre[1, :, 1].max() / MUSP)
    assert (centre[..., 1] > 0).all() and (centre[..., 1] < 0.1 * centre[..., 0]).all()
    assert read_exr_channels(out, ("determined.R",))[13, 13, 0] == 1.0
    # complete: 1 exactly where every ring lies whole on the grid (all points are lit). The rings
    # are 0 .. 5 (max_radius 6 less half a ring), one grid step thick: the last holds the offsets
    # closer than 6, as far as 5 steps along each axis, so a pixel 5 steps or more from every edge.
    complete = read_exr_channels(out, ("complete",))[..., 0]
    inner = np.zeros(complete.shape, bool)
    inner[5:-5, 5:-5] = True
    np.testing.assert_array_equal(complete, inner.astype(np.float32))
    # The header says what the numbers mean: units, pitch, n, g, the errors' source and the rig's scale.
    with OpenEXR.File(str(out)) as exr:
        header = dict(exr.header())  # the file's own dict is emptied when it closes
    assert header["ringlight.units"] == "per_mm" and header["ringlight.noise"] == "ring spread"
    assert header["ringlight.pitch_mm"] == pytest.approx(0.1) and header["ringlight.n"] == pytest.approx(1.4)
    assert header["ringlight.g"] == 0.0 and header["ringlight.scale"] == "1 1 1"
    result = json.loads(document.read_text())
    assert result["units"] == "per_mm" and result["n"] == 1.4 and result["g"] == 0.0
    assert list(result["R_d"]) == ["0", "0.5", "1."]  # keyed as written, cycles per mm
    np.testing.assert_allclose(result["mua"], MUA, rtol=0.02)
    np.testing.assert_allclose(result["musp"], MUSP, rtol=0.02)
    rd = np.array(list(result["R_d"].values()))
    assert (np.diff(rd, axis=0) < 0).all()  # R_d falls with frequency in every channel
    printed = capsys.readouterr().out
    assert "wrote" in printed
    # The printed line gives the JSON's values with their standard errors (two significant digits).
    line = next(line for line in printed.splitlines() if line.startswith("region: "))
    assert line.endswith(" per mm (R / G / B, ±1 SE)"), line
    pairs = [(float(value), float(error)) for value, error in re.findall(r"([0-9.]+)±([0-9.]+)", line)]
    assert len(pairs) == 6, line
    for (value, error), expected, expected_error in zip(pairs, result["mua"] + result["musp"],
                                                        result["mua_se"] + result["musp_se"]):
        assert error == pytest.approx(expected_error, rel=0.05)
        assert abs(value - expected) <= 0.051 * expected_error


def test_the_printed_region_names_the_channels_not_determined(homogeneous, tmp_path, monkeypatch, capsys):
    from ringlight.app.cli import optics as command

    fit = command.region_optics

    def blue_undetermined(*args, **kwargs):
        result = fit(*args, **kwargs)
        assert result.determined.all()  # the homogeneous dataset is determined in every channel
        return dataclasses.replace(result, determined=np.array([True, True, False]))

    monkeypatch.setattr(command, "region_optics", blue_undetermined)
    assert main(["optics", homogeneous, "--json", str(tmp_path / "region.json"), *PHOTONS]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("region: "))
    assert line.endswith("(R / G / B, ±1 SE); not determined in B"), line


def test_the_white_run_of_a_regions_fit_is_traced_once_with_its_progress(homogeneous, tmp_path, monkeypatch,
                                                                         caplog):
    """An empty user cache: ``--json`` alone traced the table's white run inside the region's fit,
    with no progress (about 50 s at the default photons on two cores, after a line saying it ran).
    It is traced first, its progress logged, and the fit reads it from the cache: one run."""
    monkeypatch.setenv("RINGLIGHT_LOG", "info")  # every step's line (the command sets its logger's level)
    caplog.set_level("INFO", logger="ringlight")
    traced = []
    trace = radial.run_radial
    monkeypatch.setattr(radial, "run_radial", lambda *args, **kwargs: traced.append(args) or trace(*args, **kwargs))
    assert main(["optics", homogeneous, "--json", str(tmp_path / "region.json"), *PHOTONS]) == 0
    lines = [record.getMessage() for record in caplog.records]
    assert [line for line in lines if re.fullmatch(r"white run on CPU \(\d+ cores?\): +100%", line)], lines
    assert len(traced) == 1


def test_a_calibration_made_on_a_reference_is_taken_by_later_maps(homogeneous, tmp_path, capsys):
    calibration = tmp_path / "rig.json"
    assert main(["optics", homogeneous, "--write-calibration", str(calibration), "--reference-mua", "0.2",
                 "--reference-musp", "2.5,5,10", *PHOTONS]) == 0
    scale = json.loads(calibration.read_text())["scale"]
    # The green channel's reference is the truth (scale 1); red's and blue's musp are off by 2x,
    # which a single scale cannot absorb: far from 1.
    assert scale[1] == pytest.approx(1.0, rel=0.01) and abs(scale[0] - 1) > 0.05 and abs(scale[2] - 1) > 0.05
    document = tmp_path / "region.json"
    assert main(["optics", homogeneous, "--json", str(document), "--calibration", str(calibration), *PHOTONS]) == 0
    assert json.loads(document.read_text())["mua"][1] == pytest.approx(MUA, rel=0.02)


@pytest.mark.parametrize("arguments, message", [
    ([], "give --out, --json or --write-calibration"),
    (["--json", "r.json", "--mtf", "0,x"], "--mtf '0,x' must be numbers"),
    (["--json", "r.json", "--mtf", "-1"], "--mtf '-1' must be finite non-negative"),
    (["--write-calibration", "c.json", "--reference-mua", "0.1"], "--reference-mua and --reference-musp"),
    (["--json", "r.json", "--calibration", "missing.json"], "missing.json"),
    (["--json", "r.json", "--n", "0.3"], "n must lie in [1, 3]"),
])
def test_bad_arguments_are_one_line_and_exit_2(homogeneous, tmp_path, monkeypatch, capsys, arguments, message):
    monkeypatch.chdir(tmp_path)
    assert main(["optics", homogeneous, *arguments, *PHOTONS]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and "\n" not in error and "Traceback" not in error
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("photons", ["0", "-5", "9999", "100000001"])
def test_a_white_run_outside_the_photon_range_is_refused_before_the_dataset_is_read(tmp_path, capsys, photons):
    """``--photons 0`` traced 16 photons and mapped skin1 37 % off in mu_s', silently. The range is
    checked first: a dataset that does not exist is not what the one line names."""
    assert main(["optics", str(tmp_path / "missing"), "--json", str(tmp_path / "r.json"), "--photons", photons]) == 2
    error = capsys.readouterr().err.strip()
    assert error == ("ringlight: error: photons of the white run must be a whole number from 10000 to 100000000, "
                     f"got {photons}")
    assert not (tmp_path / "r.json").exists()


def test_every_public_fit_refuses_a_table_of_too_few_photons(homogeneous):
    from ringlight.core import open_dataset
    from ringlight.core.optics import calibrate, model_profile, optical_maps, reflectance_maps, region_optics
    from ringlight.core.optics.radial import TableError

    dataset = open_dataset(homogeneous)
    maps = optical_maps(dataset, photons=TEST_PHOTONS)  # R_d maps take its table's photons apart
    calls = (lambda: optical_maps(dataset, photons=16), lambda: region_optics(dataset, photons=16),
             lambda: calibrate(dataset, 0.2, 5.0, photons=16),
             lambda: model_profile(0.2, 5.0, np.arange(6.0), n=1.4, photons=16),
             lambda: reflectance_maps(maps, np.ones((6, 26, 26, 3), np.float32), [0.0], photons=16))
    for call in calls:
        with pytest.raises(TableError, match="from 10000 to 100000000, got 16"):
            call()


@pytest.mark.parametrize("arguments, message", [
    (["--json", "r.json", "--roi", "0,0,99,99"], "inside the 26 x 26 grid"),
    (["--out", "m.exr", "--roi", "0,0,4,4"], "--roi, --layers and --mtf are for the region of --json"),
    (["--out", "m.exr", "--layers", "2"], "--roi, --layers and --mtf are for the region of --json"),
    (["--out", "m.exr", "--mtf", "0,0.1"], "--roi, --layers and --mtf are for the region of --json"),
    (["--json", "r.json", "--reference-mua", "0.1", "--reference-musp", "1"],
     "describe the reference of --write-calibration"),
    (["--json", "r.json", "--reference-description", "a phantom"], "describe the reference of --write-calibration"),
])
def test_options_that_cannot_apply_are_refused_before_the_white_run(homogeneous, tmp_path, monkeypatch, capsys,
                                                                    arguments, message):
    """A region outside the grid was refused only after the white run and the maps (a minute at the
    default photons), and the reference's options without ``--write-calibration`` were ignored:
    the user believed the rig calibrated. Each is one line before any run (none is in the cache)."""
    monkeypatch.chdir(tmp_path)
    assert main(["optics", homogeneous, *arguments, "--photons", "12345"]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and "\n" not in error
    assert not radial.radial_path(1.4, 0.0, 12345, 0).exists() and not list(tmp_path.iterdir())


def test_an_existing_file_is_not_replaced_without_force(homogeneous, tmp_path, capsys):
    out = tmp_path / "maps.exr"
    out.write_bytes(b"mine")
    assert main(["optics", homogeneous, "--out", str(out), *PHOTONS]) == 2
    assert "already exists" in capsys.readouterr().err and out.read_bytes() == b"mine"
