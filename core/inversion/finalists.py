"""The last stage of a layer inversion's search (:mod:`.layers`): which structures are fitted fully.

A search ranks structures by quick fits on thinned databases (:mod:`.search`: a quarter of
:attr:`~.settings.InversionSettings.photons`, 5 000 photons by default), whose own noise at the
outer rings is larger than the differences between neighbouring boundaries: on a held-out
three-layer slab it ranked boundaries [2, 4] and [2, 6] above the truth's [2, 5], which then fitted
best of the three with a million photons (chi-square 24.5 against 37.7 and 30.4 for 27 degrees of
freedom) and was not among the rivals fitted at the end. So the search's choice, its rivals and
its choice's boundary neighbours (:func:`.search.boundary_moves`) are *screened*: quick fits on a
final white run of each (:mod:`.white_cells`, cached), and where a neighbour fits better, its own
neighbours in turn (a local search over boundaries on full-photon fits, :data:`MAX_ROUNDS` at most).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from .fit import fit_channels
from .measured import MeasuredProfile
from .search import Candidate, bic, boundary_moves
from .settings import InversionSettings
from .cell_forward import CellForward
from .white_cells import cell_database

MAX_ROUNDS = 3
"""Rounds of the local search over boundaries at most (each screens the leader's neighbours)."""


def screen(settings: InversionSettings, starts: list[Candidate], bins: int, measured: MeasuredProfile,
           report: Callable[[float, str], None], first: float, span: float, device=None) -> list[Candidate]:
    """Screen ``starts`` (the search's choice first, then its rivals) and the boundary neighbours
    (within ``bins`` depth bins) of the leader, round by round: each candidate's quick fit (no
    intervals) with a white run of ``settings.final_photons``. Returns every candidate screened,
    its BIC and chi-square those of that fit, best BIC first; progress goes from ``first`` over
    ``span``; the white runs run on ``device`` (:func:`ringlight.core.device.choose_device`'s; None:
    the CPU)."""
    screened: dict[tuple, Candidate] = {}
    frontier = list(starts)
    for round_number in range(MAX_ROUNDS):
        frontier += [Candidate(math.inf, math.inf, mus, structure, optics)
                     for structure, optics, mus in boundary_moves(settings, frontier[0], bins)]
        todo = list({_key(c): c for c in frontier if _key(c) not in screened}.values())
        for number, candidate in enumerate(todo):
            done = first + span * (round_number + number / len(todo)) / MAX_ROUNDS
            each = span / MAX_ROUNDS / len(todo)
            what = (f"white Monte Carlo of {settings.final_photons} photons for boundaries "
                    f"{list(candidate.structure.starts[1:]) or 'none'}")
            report(done, what)
            cells = cell_database(candidate.optics, candidate.structure, settings.final_photons, device=device,
                                  progress=lambda fraction: report(done + 0.5 * fraction * each, what))
            forward = CellForward(cells, candidate.structure, measured.radii, ring_weights=measured.ring_weights)
            fits = fit_channels(forward, measured.mean, measured.standard_error, intervals=False, floor=measured.floor)
            chi2 = sum(f.chi2 for f in fits)
            screened[_key(candidate)] = candidate._replace(
                bic=bic(chi2, sum(f.used for f in fits), candidate.structure, candidate.mus), chi2=chi2)
        ranked = sorted(screened.values(), key=lambda c: c.bic)
        if _key(ranked[0]) == _key(frontier[0]):
            break  # the leader's neighbours are screened and none fits better
        frontier = [ranked[0]]
    return sorted(screened.values(), key=lambda c: c.bic)


def _key(candidate: Candidate) -> tuple:
    """What identifies a candidate's model: its structure and its white run's optics."""
    return candidate.structure, candidate.optics
