"""Launching ringlight: one clear line instead of a Qt abort or a window for a typo; helpful --help."""

import subprocess
import sys

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
                            timeout=60, env={k: v for k, v in __import__("os").environ.items()})
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ringlight: error: no display to open a window on")


def test_missing_xcb_cursor_is_named(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(main_module.ctypes.util, "find_library", lambda name: None)
    assert "apt install libxcb-cursor0" in main_module.display_problem()


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
    assert err.strip() == "ringlight: error: --radii '10,5,1' must be non-negative and increase strictly, e.g. 2,5,8"
