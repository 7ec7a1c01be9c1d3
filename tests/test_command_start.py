"""A ``ringlight`` command starts without loading what only a fit needs: scipy.optimize and
scipy.stats took 1.1-1.3 s of CPU to import, over a third of every command's start (the docs
pages run 36 commands, each in its own process). A command that opens a dataset still loads
scipy later, through colour-science (``colourspaces.parse_colourspace``)."""

import subprocess
import sys

from scipy.stats import chi2

from ringlight.core.inversion.joint import ELLIPSE_CHI2


def test_the_command_line_loads_no_optimiser_until_it_fits():
    code = ("import sys, ringlight.app.cli; "
            "print(sorted(m for m in sys.modules if m.startswith(('scipy.optimize', 'scipy.stats'))))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_the_ellipse_quantile_is_scipys_chi_square_quantile():
    # Written in closed form (2 degrees of freedom: -2 ln(1 - p)) so that joint.py needs no scipy.stats.
    assert ELLIPSE_CHI2 == float(chi2.ppf(0.954, 2))
