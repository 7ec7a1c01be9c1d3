"""The search of a layer inversion (:mod:`.layers`): the candidates it tries and how it ranks
them (BIC), the white databases' optics for a structure and scattering, the structures tried, the
base of a scattering of its own, and the refinement of the scattering between :data:`MUS_GRID`'s
values with the boundaries."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import NamedTuple

from .forward import Structure
from .settings import MAX_LAYERS, MUS_GRID, SEARCH_BINS, InversionSettings
from .white_mc import SlabOptics

REACH = 13
"""Pixels from the lit point (in y and in x) that a white database keeps."""
REFINE_STEPS = (2 ** 0.5, 2 ** 0.25)
"""Factors by which the chosen scattering is refined, in turn, between :data:`MUS_GRID`'s values
(to within 2^(1/8), 9 %)."""
REFINE_MOVES = 4
"""Moves of the refinement's local search at most, per step."""

class Candidate(NamedTuple):
    """One structure tried in a search: its BIC and chi-square (quick fit), scattering, and the optics
    of its white database (the few fitted fully get a white run of their own, :mod:`.white_cells`)."""

    bic: float
    chi2: float
    mus: float | tuple[float, ...]
    structure: Structure
    optics: SlabOptics


def best_candidate(candidates: list[Candidate]) -> Candidate | None:
    """The candidate of lowest BIC, or None when no fit succeeded."""
    return min((c for c in candidates if math.isfinite(c.bic)), key=lambda c: c.bic, default=None)


def bic(chi2: float, points: int, structure: Structure, mus) -> float:
    """The Bayesian information criterion of a fit of ``points`` rings (every channel's): each
    channel's absorption per layer is an unknown, and a base with a scattering of its own
    (``mus`` a tuple) one more; infinite for a fit that failed."""
    unknowns = 3 * structure.layers + (1 if isinstance(mus, tuple) else 0)
    return chi2 + unknowns * math.log(max(points, 1)) if math.isfinite(chi2) else math.inf


def search_base(settings: InversionSettings, n: float, structures: list[Structure], candidates: list[Candidate],
                 try_structures, fraction_done: Callable[[float], float]) -> None:
    """Try structures of two or more layers again with a base that scatters otherwise than the
    layers above: every pair of scatterings of :data:`MUS_GRID` on those of ``structures`` with even
    boundaries, then every other one with the pair that fitted best. A thin upper layer over a base
    that scatters otherwise (skin over flesh) is the common case; one scattering for all may then
    fit a wrong structure as well as the right one, with regions that leave out the truth, or fit
    none. ``try_structures`` adds its quick fits to ``candidates``; every database has index ``n``."""
    def trial(structure: Structure, common: float, base: float):
        return (structure, base_optics(settings, common, base, structure.starts[-1], n),
                (common,) * (structure.layers - 1) + (base,))

    scouts = scout_structures([structure for structure in structures if structure.layers > 1])
    first = len(candidates)
    try_structures([trial(structure, common, base) for common in MUS_GRID for base in MUS_GRID if base != common
                    for structure in scouts], fraction_done(0.0),
                   "fitting structures with a base that scatters otherwise", fraction_done(0.5) - fraction_done(0.0))
    chosen = best_candidate(candidates[first:])
    if chosen is None:
        return
    common, base = chosen.mus[0], chosen.mus[-1]
    rest = [structure for structure in structures if structure.layers > 1 and structure not in scouts]
    try_structures([trial(structure, common, base) for structure in rest], fraction_done(0.5),
                   f"fitting every structure with mus {common:g} over a base of {base:g}",
                   fraction_done(1.0) - fraction_done(0.5))


def refine_scattering(settings: InversionSettings, leading: Candidate, bins: int, candidates: list[Candidate],
                       try_structures, first: float, share: float) -> None:
    """Refine the ``leading`` candidate's scattering between the values of :data:`MUS_GRID`
    (factors of 2 apart) together with its boundaries, by a local search: at each step of
    :data:`REFINE_STEPS`, the moves are its common scattering and (when it has one) its base's that
    factor lower or higher, and each searched boundary one depth bin up or down (within ``bins``); the best
    move that fits better is taken, at most :data:`REFINE_MOVES` times a step (progress from
    ``first``, a ``share`` a step). A sample whose
    scattering lies between grid values otherwise fits a nearby value, often with a boundary moved
    to make up for it (layers3, base 1.5 and boundaries 2, 5: fitted at base 1 with 2, 4, the middle
    layer 0.067 off in xy and its truth outside its region)."""
    n = leading.optics.n
    current = leading
    tried = {(c.structure, c.mus) for c in candidates}
    for number, step in enumerate(REFINE_STEPS):
        for move in range(REFINE_MOVES):
            trials = [trial for trial in _moves(settings, current, step, bins, n) if (trial[0], trial[2]) not in tried]
            tried.update((trial[0], trial[2]) for trial in trials)
            if not trials:
                break
            start = len(candidates)
            try_structures(trials, first + (number + move / REFINE_MOVES) * share,
                           f"refining the scattering and boundaries (factor {step:.3g})", share / REFINE_MOVES)
            moved = min([current, *candidates[start:]], key=lambda c: c.bic)
            if moved is current:
                break
            current = moved


def _moves(settings: InversionSettings, current: Candidate, step: float, bins: int, n: float):
    """``(structure, optics, mus)`` of each move of :func:`refine_scattering` from ``current``."""
    common, base = _common_and_base(current.mus)
    own_base = isinstance(current.mus, tuple)
    pairs = [(_rounded(common * factor), _rounded(base * factor) if not own_base else base)
             for factor in (1 / step, step)]
    if own_base:
        pairs += [(common, _rounded(base * factor)) for factor in (1 / step, step)]
    for first, last in pairs:
        yield _trial(settings, current.structure, first, last, n)
    yield from boundary_moves(settings, current, bins)


def boundary_moves(settings: InversionSettings, current: Candidate, bins: int):
    """``(structure, optics, mus)`` of ``current`` with one searched boundary a depth bin up or down
    (within ``bins``; none when the boundaries are given), its scattering and index kept."""
    common, base = _common_and_base(current.mus)
    cuts = list(current.structure.starts[1:]) if settings.boundaries is None else []  # given boundaries stay
    for k in range(len(cuts)):
        for shift in (-1, 1):
            moved = cuts[:k] + [cuts[k] + shift] + cuts[k + 1:]
            if all(a < b for a, b in zip([0, *moved], moved)) and moved[-1] < bins:
                yield _trial(settings, Structure((0, *moved)), common, base, current.optics.n)


def _common_and_base(mus) -> tuple[float, float]:
    """The scattering of the upper layers and of the base of a candidate's ``mus``."""
    return (mus[0], mus[-1]) if isinstance(mus, tuple) else (mus, mus)


def _trial(settings: InversionSettings, structure: Structure, common: float, base: float, n: float):
    """``(structure, optics, mus)``: ``structure`` scattering ``common`` over a base of ``base``."""
    if common == base or structure.layers == 1:
        return structure, database_optics(settings, common, n), common
    return (structure, base_optics(settings, common, base, structure.starts[-1], n),
            (common,) * (structure.layers - 1) + (base,))


def _rounded(mus: float) -> float:
    """``mus`` to 4 significant digits (as reports print it)."""
    return float(f"{mus:.4g}")


def database_optics(settings: InversionSettings, mus, n: float | None = None) -> SlabOptics:
    """The white database's optics at index ``n`` (default: ``settings.n``): per-layer scattering
    over the given boundaries, or a common one over :data:`SEARCH_BINS` bins (more when a given
    boundary lies deeper: a bin per grid step down to the last boundary, then the base)."""
    n = settings.n if n is None else n
    if isinstance(mus, tuple):
        edges = [0, *settings.boundaries]
        bins = []
        for k, top in enumerate(edges):
            bottom = edges[k + 1] if k + 1 < len(edges) else top + 1
            bins += [mus[k]] * (bottom - top)
        return _optics(settings, bins, n)
    deepest = settings.boundaries[-1] + 1 if settings.boundaries else 0
    return _optics(settings, [mus] * max(SEARCH_BINS, deepest), n)


def base_optics(settings: InversionSettings, common: float, base: float, top: int, n: float) -> SlabOptics:
    """A database's optics at index ``n`` for a structure whose base, from bin ``top`` down,
    scatters with ``base`` and every bin above with ``common``."""
    return _optics(settings, [common if b < top else base for b in range(max(SEARCH_BINS, top + 1))], n)


def _optics(settings: InversionSettings, bins, n: float) -> SlabOptics:
    """Optics of scattering ``bins`` per depth bin at index ``n``, with ``settings``' g and depth."""
    if n is None:
        raise ValueError("a white database needs a refractive index")
    return SlabOptics(tuple(float(m) for m in bins), settings.anisotropy, float(n), settings.depth, REACH)


def all_structures(settings: InversionSettings, bins: int, most_layers: int):
    """Every structure to try, of at most ``most_layers`` layers when their count is searched."""
    if settings.boundaries is not None:
        yield Structure((0, *settings.boundaries))
        return
    counts = [settings.layers] if settings.layers is not None else range(1, min(MAX_LAYERS, most_layers) + 1)
    for count in counts:
        for cut in itertools.combinations(range(1, bins), count - 1):
            yield Structure((0, *cut))


def scout_structures(structures: list[Structure]) -> list[Structure]:
    """The structures whose boundaries all lie at even depths (all of them if none does)."""
    even = [structure for structure in structures if all(b % 2 == 0 for b in structure.starts[1:])]
    return even or structures
