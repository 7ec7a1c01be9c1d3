"""The last stage of a layer search (ringlight.core.inversion.finalists): structures ranked again
by quick fits with final white runs, and a local search over boundaries on those fits."""

from __future__ import annotations

import math

from ringlight.core.inversion.finalists import screen
from ringlight.core.inversion.forward import Structure
from ringlight.core.inversion.measured import MeasuredProfile
from ringlight.core.inversion.search import Candidate, database_optics
from ringlight.core.inversion.settings import InversionSettings

from test_inversion import RADII, direct_profile


def test_screening_climbs_from_a_boundary_two_bins_off_to_the_truths(tmp_path, monkeypatch):
    """A two-layer slab made by the direct simulator (independent walks with absorption), boundary
    at 3: started from boundary 5, the screen's rounds (5 and its neighbours 4 and 6, then 4's
    neighbour 3, then 3's neighbour 2) rank the truth's boundary first, and stop there."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    mua = [[0.3, 0.05, 0.01], [0.01, 0.02, 0.2]]
    mean, error = direct_profile([1.0, 1.0], mua, [0, 3], 0.0, 1.4, 24.0, 30_000, seed=5)
    measured = MeasuredProfile(RADII, mean, error, 1)
    settings = InversionSettings(layers=2, mus=1.0, n=1.4, g=0.0, depth=24.0, photons=20_000, final_photons=50_000)
    optics = database_optics(settings, 1.0)
    start = Candidate(math.inf, math.inf, 1.0, Structure((0, 5)), optics)
    said = []
    ranked = screen(settings, [start], optics.bins, measured, lambda fraction, what: said.append(fraction), 0.0, 1.0)
    assert ranked[0].structure == Structure((0, 3))
    assert sorted(c.structure.starts[1] for c in ranked) == [2, 3, 4, 5, 6]
    assert all(math.isfinite(c.chi2) for c in ranked) and ranked[0].chi2 < ranked[-1].chi2
    assert said == sorted(said) and 0.0 <= said[0] and said[-1] <= 1.0
