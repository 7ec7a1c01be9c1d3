"""A ``ringlight`` command starts without loading what only a fit needs: scipy.optimize and
scipy.stats took 1.1-1.3 s of CPU to import, over a third of every command's start (the docs
pages run 36 commands, each in its own process). A command that opens a dataset loads
colour-science only when it converts colours (tests/test_colour_import.py). Nor does a command
load the other commands' modules (cv2 for capture, the optics package, the inversion, the simulator)."""

import json
import subprocess
import sys

import pytest
from scipy.stats import chi2

from ringlight.core.inversion.joint import ELLIPSE_CHI2


@pytest.fixture(scope="module")
def loaded():
    """What one fresh interpreter has loaded after ``ringlight simulate --list`` (the modules of
    the command line), then after importing every command's module (the optimiser's modules):
    one process for both tests."""
    code = """if True:
        import contextlib, io, json, sys
        from ringlight.app import cli
        from ringlight.app.main import main
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["simulate", "--list"]) == 0
        commands = sorted(m for m in sys.modules if m.startswith("ringlight.app.cli."))
        others = "cv2" in sys.modules, "ringlight.core.optics" in sys.modules
        for name in cli.COMMANDS:
            __import__(f"ringlight.app.cli.{name}")
        fits = sorted(m for m in sys.modules if m.startswith(("scipy.optimize", "scipy.stats")))
        print(json.dumps({"commands": commands, "others": others, "fits": fits}))
    """
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_the_command_line_loads_no_optimiser_until_it_fits(loaded):
    assert loaded["fits"] == []


def test_a_command_loads_its_own_module_and_not_the_others(loaded):
    assert loaded["commands"] == ["ringlight.app.cli.progress", "ringlight.app.cli.simulate"]
    assert loaded["others"] == [False, False]  # cv2 (capture, layers), the optics package


def test_the_ellipse_quantile_is_scipys_chi_square_quantile():
    # Written in closed form (2 degrees of freedom: -2 ln(1 - p)) so that joint.py needs no scipy.stats.
    assert ELLIPSE_CHI2 == float(chi2.ppf(0.954, 2))
