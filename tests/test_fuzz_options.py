"""Option values of every command (info, stack, simulate, layers, capture, demo): hostile values,
one to three at a time, give ringlight's one line (or argparse's) and exit status 2, or a result
and 0; never a traceback, and within bounded memory (issue 40, cases 9, 11, 13). Hypothesis picks
the options and their values.

The pools hold values that are wrong, or right and cheap on the tiny inputs here: a value that is
valid and slow by design (a million photons, a --time of an hour) is not a reliability defect.
The issue's own cases are tested one by one below, with the memory their old code took.
"""

from __future__ import annotations

import json
import os
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import random_impulses, write_dataset
from ringlight.app.main import main

NUMBERS = ["nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "1e-320", "abc", "", "1e400", "99999999999999999999"]
FUZZ = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("inputs")
    write_dataset(folder / "ds", 6, 5, random_impulses(np.random.default_rng(0), 6, 5, support=3.0), max_radius=3.0)
    scene = {"format": "ringlight-scene", "version": 1, "grid": {"height": 3, "width": 3}, "depth": 4,
             "materials": {"m": {"mus": [1, 1, 1], "mua": [0.1, 0.1, 0.1]}}, "background": "m",
             "max_radius": 2, "path_length_bins": {"step": 1, "count": 4}, "photons_per_point": 2}
    (folder / "scene.json").write_text(json.dumps(scene))
    (folder / "a-file").write_text("not a dataset")
    os.mkfifo(folder / "fifo")
    return folder


COMMANDS = {
    # base arguments (with {ds}, {scene}, {out}, {folder}), then a pool of values per option
    "stack": (["stack", "{ds}", "--radii", "0:2:1", "--out", "{out}"], {
        "--radii": ["0:4000:1", "0:3:1e-9", "nan:3:1", "0:inf:1", "3:0:1", "a:b:c", "0:1e308:1", "-1:3:1",
                    "0:3:0", "0:3:-1", "1e-320:1:1e-320", "0:2:1", "0:2", ""],
        "--thickness": NUMBERS + ["4000", "0.5"], "--dr": NUMBERS + ["4000", "0.5"],
        "--scheduler": ["garbage", "tcp://", "", "::"], "--kind": ["ring", "both", ""],
        "--out": ["{folder}/a-file", "{folder}/a-file/x", "{folder}/" + "n" * 300, "/proc/stack", "{folder}"],
    }),
    "layers": (["layers", "{ds}", "--radii", "1,2"], {
        "--radii": ["2,1", "nan,1", "1,1", "-1,2", "1e308,1e309", "a", "", "1,2,3,4,5,6,7,8,9"],
        "--step": NUMBERS, "--dr": NUMBERS, "--thickness": NUMBERS + ["4000"],
        "--roi": ["0,0,0,0", "a,b,c,d", "0,0,99,99", "-1,-1,2,2", "1,2,3", "0,0,6,5"],
        "--json": ["", "{folder}/a-file", "{folder}", "{folder}/a-file/x.json", "/proc/x.json"],
    }),
    "layers inverse": (["layers", "{ds}", "--method", "inverse", "--photons", "1000", "--final-photons", "1000",
                        "--layers", "1"], {
        "--depth": NUMBERS + ["1000000", "9", "1025"], "--photons": ["0", "-1", "999", "1000001", "1e3", "abc"],
        "--n": NUMBERS + ["0.5", "4"], "--g": NUMBERS + ["1", "-1"], "--mus": NUMBERS + ["101", "1,2,3", ","],
        "--boundaries": ["0", "-1", "2,1", "1.5", "64", "a", "1,1"], "--layers": ["0", "5", "-1", "x", "1e3"],
    }),
    "simulate": (["simulate", "{scene}", "--out", "{out}", "--photons", "2"], {
        "--photons": ["0", "-1", "10000001", "1e308", "abc", "99999999999999999999"],
        "--noise": NUMBERS + ["1", "5", "1e-9", "0.0009"], "--time": ["soon", "0", "-1s", "infs", "1e400h", "nan", ""],
        "--size": ["0x0", "-1x4", "100000x100000", "4x4x4", "axb", "x", "", "99999999999999999999x1"],
        "--seed": ["-1", "4294967296", "abc", "1e3"], "--estimator": ["both", ""],
    }),
    "info": (["info"], {"": ["{folder}/missing", "{folder}/a-file", "{folder}", "{folder}/fifo", "", "/"]}),
    "capture": (["capture", "--camera", "simulated", "--projector", "simulated", "--option", "fail_after=0",
                 "--out", "{out}"], {
        "--max-radius": NUMBERS + ["4097"], "--multiplex": ["-1", "1", "2", "6", "2047", "65535", "1e3", "x"],
        "--roi": ["a,b,c,d", "1,2,3", "", "1,2,3,4,5"], "--camera": ["nope", ""], "--option": ["=", "size", "a=b=c"],
    }),
    "demo": (["demo"], {"--sample": ["nope", "", "../x"]}),
}


def run(capsys, argv):
    """Exit status, stderr lines and peak traced memory of ``ringlight argv``."""
    tracemalloc.start()
    try:
        try:
            status = main(argv)
        except SystemExit as exit:  # argparse's usage errors
            status = exit.code
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return status, capsys.readouterr().err.strip().splitlines(), peak


def arguments(command, chosen, inputs, out):
    base, _ = COMMANDS[command]
    names = {"ds": str(inputs / "ds"), "scene": str(inputs / "scene.json"), "out": str(out), "folder": str(inputs)}
    argv = [part.format(**names) for part in base]
    for option, value in chosen:
        value = value.format(**names)
        if option == "":
            argv.append(value)
        elif option in argv:
            argv[argv.index(option) + 1] = value
        else:
            argv += [option, value]
    return argv


@pytest.mark.parametrize("command", COMMANDS)
@FUZZ
@given(data=st.data())
def test_hostile_option_values_are_one_line_or_a_result(command, inputs, tmp_path_factory, capsys, data):
    pools = COMMANDS[command][1]
    options = data.draw(st.lists(st.sampled_from(sorted(pools)), min_size=1, max_size=3, unique=True))
    chosen = [(option, data.draw(st.sampled_from(pools[option]))) for option in options]
    out = tmp_path_factory.mktemp("out") / "out"
    argv = arguments(command, chosen, inputs, out)
    status, err, peak = run(capsys, argv)
    assert status in (0, 2), (argv, status, err)
    assert not any("Traceback" in line for line in err), (argv, err)
    if status == 2:
        assert err and (err[-1].startswith("ringlight: error: ") or ": error: " in err[-1]), (argv, err)
    assert peak < 512 * 2**20, (argv, f"{peak / 2**20:.0f} MiB")


@pytest.mark.parametrize("radii, thickness, expected", [
    # A transient at r uses the ring r + 1 (dr = 1): the first that reaches beyond max_radius 3 is
    # named, with the radii that work. Ring 3's members (|d| < 3.5) include (3, 1), 3.162 away;
    # every ring of thickness 4000 reaches about 2000.
    ("0:4000:1", "1", "the ring of radius 3 (thickness 1) reaches 3.162 grid steps, beyond the dataset's "
                      "max_radius 3; transient radii (dr 1) up to 1 work (radii 0:1:1)"),
    ("0:3:1", "4000", "the ring of radius 1 (thickness 4000) reaches 2000.998 grid steps, beyond the dataset's "
                      "max_radius 3; no transient radii (dr 1) of those requested work"),
])
def test_a_stack_beyond_max_radius_is_refused_before_its_rings_are_built(inputs, tmp_path, capsys, radii, thickness,
                                                                         expected):
    """Case 13: 2.3 GB and 1.4 GB of rings were built before the one-line refusal."""
    status, err, peak = run(capsys, ["stack", str(inputs / "ds"), "--radii", radii, "--thickness", thickness,
                                     "--out", str(tmp_path / "out")])
    assert status == 2 and err[-1] == f"ringlight: error: {inputs / 'ds'}: {expected}"
    assert peak < 64 * 2**20, f"{peak / 2**20:.0f} MiB"
    assert not (tmp_path / "out").exists()


def test_an_inversion_deeper_than_the_rings_reach_is_refused_before_the_dataset_opens(inputs, capsys):
    """Case 11: --depth 1000000 ran for minutes of CPU."""
    status, err, _ = run(capsys, ["layers", str(inputs / "ds"), "--method", "inverse", "--depth", "1000000"])
    assert status == 2 and err == ["ringlight: error: the modelled depth must be at most 1024 grid steps (a deeper "
                                   "slab only lengthens the walks: light from below does not reach the rings), got 1e+06"]


def test_a_noise_target_that_cannot_be_reached_is_refused(inputs, tmp_path, capsys):
    status, err, _ = run(capsys, ["simulate", str(inputs / "scene.json"), "--out", str(tmp_path / "out"),
                                  "--noise", "1e-320"])
    assert status == 2 and err == ["ringlight: error: --noise must be a fraction from 0.001 to below 1, e.g. 0.05, "
                                   "got 1e-320"]


def test_a_dark_frame_that_overflows_the_steady_state_is_one_line(tmp_path, capsys):
    """Case 14: a dark frame of 3e38 printed numpy's "overflow encountered in cast", exited 0 and
    left a steady state of -inf (every frame minus 3e38, summed over 30 frames: -9e39)."""
    from reference import write_rgb

    write_dataset(tmp_path / "ds", 6, 5, random_impulses(np.random.default_rng(0), 6, 5, support=3.0),
                  max_radius=3.0, extra={"dark": "dark.exr"})
    write_rgb(tmp_path / "ds" / "dark.exr", np.full((6, 5, 3), 3e38, np.float32))
    status, err, _ = run(capsys, ["stack", str(tmp_path / "ds"), "--radii", "0:2:1", "--kind", "ring",
                                  "--out", str(tmp_path / "out")])
    assert status == 2 and len(err) == 1
    assert err[0].startswith(f"ringlight: error: {tmp_path / 'ds'}: the steady state (the sum of all frames) at grid "
                             "point [0, 0] is -")
    assert err[0].endswith("beyond float32's range: check the frames' values, exposures and dark frame "
                           "(dark frame dark.exr)")
    assert not (tmp_path / "out").exists()
