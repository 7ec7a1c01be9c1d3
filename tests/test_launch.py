"""Launching ringlight: one clear line instead of a Qt abort or a window for a typo; helpful --help."""

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ringlight.app import main as main_module
from ringlight.app.main import main


def run(capsys, *argv):
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_a_mistyped_command_is_refused_before_any_window(capsys):
    status, out, err = run(capsys, "simulat")
    assert status == 2 and out == ""
    assert err.strip().splitlines() == [
        "ringlight: error: simulat: no such dataset folder or command; did you mean 'ringlight simulate'?"]


def test_no_display_gives_one_line_and_no_abort(monkeypatch):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"):
        monkeypatch.delenv(name, raising=False)
    # In a child process: without the check, Qt aborts it (SIGABRT, exit 134).
    result = subprocess.run([sys.executable, "-m", "ringlight.app.main"], capture_output=True, text=True,
                            timeout=60, env=dict(os.environ))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ringlight: error: no display to open a window on")


@pytest.mark.parametrize("platform, needed", [("xcb", "DISPLAY"), ("wayland", "WAYLAND_DISPLAY"),
                                               ("wayland;xcb", "WAYLAND_DISPLAY or DISPLAY")])
def test_a_display_platform_without_its_display_gives_one_line_and_no_abort(platform, needed):
    env = {name: value for name, value in os.environ.items() if name not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["QT_QPA_PLATFORM"] = platform
    # Before the check looked at a set QT_QPA_PLATFORM, Qt aborted here (SIGABRT, exit 134).
    result = subprocess.run([sys.executable, "-m", "ringlight.app.main"], capture_output=True, text=True,
                            timeout=60, env=env)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.splitlines() == [
        f"ringlight: error: no display to open a window on (QT_QPA_PLATFORM={platform} needs {needed}, which "
        "is unset); run it on a desktop, or use --screenshot FILE.png, or the command-line tools (ringlight --help)"]


@pytest.mark.parametrize("platform", ["offscreen", "minimal", "eglfs", "vnc:size=800x600", "wayland;offscreen"])
def test_platforms_without_a_display_server_are_let_through(monkeypatch, platform):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("QT_QPA_PLATFORM", platform)
    assert main_module.display_problem() is None


def test_xcb_asked_for_on_wayland_still_needs_x11_and_its_cursor_library(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setenv("QT_QPA_PLATFORM", "xcb")
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    monkeypatch.delenv("DISPLAY", raising=False)
    assert "QT_QPA_PLATFORM=xcb needs DISPLAY, which is unset" in main_module.display_problem()
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(main_module.ctypes.util, "find_library", lambda name: None)
    assert "apt install libxcb-cursor0" in main_module.display_problem()


def test_missing_xcb_cursor_is_named(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(main_module.ctypes.util, "find_library", lambda name: None)
    assert "apt install libxcb-cursor0" in main_module.display_problem()


def test_every_xcb_library_qt_loads_that_is_missing_is_named_with_its_package(monkeypatch):
    """This machine had libxcb-cursor but not libxcb-icccm or libxcb-keysyms, which the plugin also
    loads: the check passed and Qt aborted. Every library of ``ldd libqxcb.so`` is checked."""
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":99")
    absent = {"xcb-icccm", "xcb-keysyms"}
    monkeypatch.setattr(main_module.ctypes.util, "find_library",
                        lambda name: None if name in absent else f"lib{name}.so")
    assert main_module.display_problem() == (
        "Qt needs the X11 libraries libxcb-icccm, libxcb-keysyms, not installed (Debian/Ubuntu: apt install "
        "libxcb-icccm4 libxcb-keysyms1; docs/guide/install.md lists them all)")
    absent.clear()
    assert main_module.display_problem() is None
    # The packages named are those the installation guide's apt line installs.
    guide = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "install.md").read_text()
    assert set(main_module.XCB_LIBRARIES.values()) <= set(re.findall(r"lib[a-z0-9-]+", guide))


@pytest.mark.parametrize("command", ["info", "stack", "simulate", "layers", "capture", "demo"])
def test_every_command_describes_itself_in_its_help(capsys, command):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    out = capsys.readouterr().out
    description = out.split("\n\n")[1]
    assert len(description.split()) >= 4 and not description.lstrip().startswith(("positional", "options"))


def test_capture_list_names_the_built_in_devices(capsys):
    status, out, _ = run(capsys, "capture", "--list")
    assert status == 0
    # pylon is listed where pypylon is installed (the test extra installs it); the plugins whose
    # SDK is missing are named with what to install, on stderr.
    cameras, projectors = out.splitlines()
    assert cameras in ("cameras     opencv, pylon, simulated", "cameras     opencv, simulated")
    assert projectors == "projectors  screen, simulated"


def test_layer_radii_are_checked_before_the_dataset_is_opened(capsys, tmp_path):
    # The dataset does not even exist: the radii error must come first, without loading anything.
    status, _, err = run(capsys, "layers", str(tmp_path / "absent"), "--radii", "10,5,1")
    assert status == 2
    assert err.strip() == "ringlight: error: --radii '10,5,1' must be finite, non-negative and increase strictly, e.g. 2,5,8"


@pytest.mark.parametrize(("options", "line"), [
    (["--radii", "1,nan,3"], "--radii '1,nan,3' must be finite, non-negative and increase strictly, e.g. 2,5,8"),
    (["--step", "0"], "radius step must be > 0, got 0.0"),
    (["--thickness", "nan"], "ring thickness must be > 0, got nan"),
    (["--dr", "-1"], "transient step dr must be > 0, got -1.0"),
    (["--json", ""], "--json needs a file name"),
])
def test_layer_options_that_cannot_work_are_one_line_before_the_dataset_is_opened(capsys, tmp_path, options, line):
    """--step 0 looped for good, --thickness nan gave a traceback, --radii 1,nan,3 was read as
    1, 0, 3 and --json "" wrote nothing and said nothing."""
    status, _, err = run(capsys, "layers", str(tmp_path / "absent"), *options)
    assert status == 2
    assert err.strip() == f"ringlight: error: {line}"


@pytest.mark.parametrize(("arguments", "line"), [
    (["stack", "{absent}", "--radii", "0:5:1e-9", "--out", "{out}"],
     "radii 0:5:1e-09 are more than 10000: use a larger step or a shorter range"),  # asked for 37 GiB
    (["stack", "{absent}", "--radii", "0:1e308:1", "--out", "{out}"],
     "ring radius 1e+308 reaches beyond 4096 grid steps, more than any dataset holds"),
    (["stack", "{absent}", "--radii", "0:11:1", "--thickness", "nan", "--out", "{out}"],
     "ring thickness must be > 0, got nan"),
    (["stack", "{absent}", "--radii", "0:11:1", "--thickness", "100000", "--out", "{out}"],  # a 149 GiB grid
     "rings to radius 12 of thickness 100000 reach beyond 4096 grid steps, more than any dataset holds"),
    (["stack", "{absent}", "--kind", "transient", "--radii", "0:5:1", "--dr", "inf", "--out", "{out}"],
     "transient step dr must be > 0, got inf"),
    (["simulate", "layers3", "--size", "8x8", "--photons", "99999999999999999999", "--out", "{out}"],
     "--photons must be 1 to 10,000,000 per lit point, got 99999999999999999999"),
    (["simulate", "layers3", "--size", "8x8", "--seed", "99999999999999999999", "--out", "{out}"],
     "--seed must be 0 to 4294967295, got 99999999999999999999"),
])
def test_option_values_that_cannot_work_are_one_line_before_any_work(capsys, tmp_path, arguments, line):
    """Each was a traceback, a hang or a memory blow-up (a user review of the commands' options);
    the dataset does not exist, so each is refused before anything is opened."""
    arguments = [part.format(absent=tmp_path / "absent", out=tmp_path / "out") for part in arguments]
    status, _, err = run(capsys, *arguments)
    assert status == 2 and err.strip() == f"ringlight: error: {line}"
    assert not (tmp_path / "out").exists()


def test_a_screenshot_prints_one_line_and_no_qt_notices(tmp_path):
    """--screenshot under the offscreen platform: Qt's "propagateSizeHints" notice (printed for
    every window) is dropped; what is left is the one line naming the file."""
    import numpy as np
    from reference import random_impulses, write_dataset

    write_dataset(tmp_path / "ds", 8, 8, random_impulses(np.random.default_rng(1), 8, 8, support=3.0), max_radius=3.0)
    out = tmp_path / "shot.png"
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", RINGLIGHT_CACHE_DIR=str(tmp_path / "cache"))
    result = subprocess.run([sys.executable, "-m", "ringlight.app.main", str(tmp_path / "ds"), "--screenshot", str(out)],
                            capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert out.stat().st_size > 10_000
    assert result.stderr == "" and result.stdout.strip().splitlines() == [f"wrote {out}"]


def test_a_capture_max_radius_that_overflows_the_lattice_is_refused_before_any_device_opens(capsys, tmp_path):
    """--max-radius 1e308 overflowed the lattice spacing's integer after the Gray code
    correspondence had run (a user review); the hardware plugins' own warnings may come first."""
    status, _, err = run(capsys, "capture", "--camera", "simulated", "--projector", "simulated",
                         "--out", str(tmp_path / "scan"), "--max-radius", "1e308")
    assert status == 2
    assert err.strip().splitlines()[-1] == ("ringlight: error: --max-radius must be > 0 and at most 4096 grid "
                                            "steps, got 1e+308")
    assert "Traceback" not in err and not (tmp_path / "scan").exists()


def test_a_screenshots_name_and_options_are_checked_with_the_right_option_named(tmp_path, capsys):
    """A screenshot is a PNG (``shot.jpg`` held PNG bytes); an existing one is replaced with
    ``--overwrite`` (the refusal named ``--force``, which the window's command line does not take),
    and ``--overwrite`` alone is named as what goes with ``--screenshot``."""
    def refused(*arguments):
        with pytest.raises(SystemExit) if "--screenshot" not in arguments else contextlib.nullcontext():
            assert main([str(argument) for argument in arguments]) == 2
        return capsys.readouterr().err.strip().splitlines()

    assert refused("--screenshot", tmp_path / "shot.jpg") == [
        f"ringlight: error: {tmp_path / 'shot.jpg'}: a screenshot is written as PNG: give a name ending in .png"]
    existing = tmp_path / "shot.png"
    existing.write_bytes(b"mine")
    assert refused("--screenshot", existing) == [
        f"ringlight: error: {existing}: already exists; refusing to overwrite it (choose another name, or allow "
        "overwriting: --overwrite on the command line)"]
    assert existing.read_bytes() == b"mine" and sorted(tmp_path.iterdir()) == [existing]
    assert refused("--overwrite")[-1].endswith("error: --overwrite goes with --screenshot")
    assert refused("--radius", "2", "--pick", "1,1")[-1].endswith("error: --radius and --pick go with --screenshot")


@pytest.mark.parametrize("raised, status, err", [
    (KeyboardInterrupt(), 130, "ringlight: interrupted; nothing was written\n"),
    ("kernel", 130, "ringlight: interrupted; nothing was written\n"),
    (BrokenPipeError(32, "Broken pipe"), 141, ""),
])
def test_ctrl_c_and_a_closed_pipe_end_a_command_in_one_line_or_quietly(monkeypatch, capsys, raised, status, err):
    """Ctrl-C that reached a compiled kernel came back as numba's SystemError ("returned a result
    with an exception set", a traceback); ``ringlight info DATASET | head -1`` printed "error:
    Broken pipe" and exit 2, as if the user had erred."""
    import ringlight.app.cli.info as info

    def interrupted_kernel():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function _kernel>) returned a result with an exception set")

    def handler(args):
        if raised == "kernel":
            interrupted_kernel()
        raise raised

    monkeypatch.setattr(info, "run_info", handler)
    assert main(["info", "anything"]) == status
    assert capsys.readouterr().err == err


def test_ctrl_c_while_ringlight_still_imports_is_one_line(tmp_path):
    """A Ctrl-C in a command's first second (numpy, numba and the library still importing) printed
    the traceback of the import it interrupted: the console script imports them inside main."""
    environment = {**os.environ, "RINGLIGHT_CACHE_DIR": str(tmp_path / "cache")}
    process = subprocess.Popen([sys.executable, "-c", "import sys; from ringlight.app.main import main; "
                                "sys.exit(main())", "simulate", "layers3", "--out", str(tmp_path / "sim")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment)
    time.sleep(0.3)  # the interpreter is up (its SIGINT handler set), the imports have begun
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130 and err.splitlines()[-1:] == ["ringlight: interrupted; nothing was written"], err
    assert "Traceback" not in err and not (tmp_path / "sim").exists()
