"""Layer colours by inversion: fit a layered slab to a region's ring-light profiles.

The model (:mod:`.forward`, :mod:`.white_mc`): layers of a common or given scattering coefficient,
each with its own absorption per channel, anisotropy ``g`` given, refractive index ``n`` given or
chosen from :data:`~.settings.N_GRID` like the scattering (the index sets how much light the
surface reflects back in, and so the profile's shape: assuming 1.4 for an index-matched slab
misplaced its top layer's colour by 0.041 xy). The structure (layer boundaries, whole grid steps
down to :data:`~.settings.SEARCH_BINS` - 1) is given or searched by chi-square; the number of layers is given
or chosen by BIC. The scattering is given (common or per layer) or chosen from :data:`MUS_GRID`:
common to every layer, or one for the layers above and another for the base (:func:`.search.search_base`),
by BIC. The search compares quick per-channel fits (:mod:`.fit`) on thinned databases; its choice,
the structures that fit about as well and the choice's boundary neighbours are ranked again by
quick fits with a white run of their own of :attr:`~.settings.InversionSettings.final_photons`
tallied in cells (:mod:`.finalists`, :mod:`.white_cells`); the best of those and the ones that fit
about as well are fitted fully, per channel and with the channels together (:mod:`.joint`), and
the one whose joint fit is best by BIC is reported. Each layer's colour and its two-sigma region
in xy: :mod:`.layer_colour`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..device import choose_device
from .fit import JOINT_CHI2, ChannelFit, fit_channels
from .forward import Forward, weights_reach
from .joint import JointFit, fit_jointly
from .layer_colour import InvertedLayer, joined, layer_colours, widened
from .limit import data_limits, exact_regions, limit_reason
from .measured import MeasuredProfile
from .settings import MUS_GRID, N_GRID, InversionError, InversionSettings
from .cell_forward import CellForward
from .white_cells import cell_database
from .finalists import screen
from .search import (REACH, REFINE_STEPS, Candidate, all_structures, best_candidate, bic, database_optics,
                     refine_scattering, scout_structures, search_base)
from .white_mc import SlabOptics, WhiteDatabase, white_database

SEARCH_SHARE = 4
"""A structure search fits with one in this many of the database's photons; the chosen one is
fitted again with all."""
PLAUSIBLE_CHI2 = JOINT_CHI2
"""Structures (and scatterings, and indices) whose search chi-square is within this of the chosen
one's are fitted too, and each layer's region spans theirs (the same threshold as a layer's region)."""
MAX_RIVALS = 4
"""At most this many of them (the best-fitting), to bound the time."""
MISFIT_P = 1e-3
"""A fit whose chi-square is this improbable under the model is reported as not fitting, and none
of its layers as determined."""


@dataclass(frozen=True, eq=False)
class Inversion:
    """The fit of one region.

    Attributes
    ----------
    layers
        The layers, top first.
    measured
        The region's profile that was fitted.
    model, sigma
        (R, 3) the fitted E(r) and the standard deviation each ring was weighted by.
    used
        (3,) rings fitted per channel (from r = 0).
    chi2, dof
        Chi-square of the fit over every channel and its degrees of freedom.
    warning
        Why the model may not fit (chi-square too large), or None.
    notes
        How the structure and scattering were chosen.
    seconds
        Time the fit took (databases included).
    """

    layers: list[InvertedLayer]
    measured: MeasuredProfile
    model: np.ndarray
    sigma: np.ndarray
    used: np.ndarray
    chi2: float
    dof: int
    warning: str | None
    notes: str
    seconds: float

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / self.dof if self.dof else math.nan


Progress = Callable[[float, str], None]


class Fitted(NamedTuple):
    """A candidate fitted with its own white run of the final photons (``forward``, from cells):
    per channel, and jointly (None when that failed)."""

    candidate: Candidate
    fits: list[ChannelFit]
    joint: JointFit | None
    forward: CellForward

    def misfit(self, together: bool) -> tuple[float, int]:
        """Minus twice the log-likelihood (up to a constant) and residual count of the joint fit
        (``together``: its deviance, which counts its covariance too), or chi-square and count of
        the channels' own fits."""
        if together:
            return self.joint.deviance, self.joint.points
        return sum(f.chi2 for f in self.fits), sum(f.used for f in self.fits)


def invert(measured: MeasuredProfile, settings: InversionSettings, colorspace: str = "sRGB",
           progress: Progress | None = None) -> Inversion:
    """Fit ``measured`` (R, 3) as ``settings`` say; ``progress(fraction, what)`` is called along
    the way (raise from it to cancel)."""
    settings.check()
    device = choose_device(settings.device)
    start = time.perf_counter()
    report = progress or (lambda fraction, what: None)
    if not np.isfinite(measured.mean).any():
        raise InversionError("the region's profile holds no values")
    if (weights_reach(measured.ring_weights) if measured.ring_weights is not None
            else measured.radii.max(initial=0.0)) > REACH:
        raise InversionError(f"the profile's rings reach beyond the {REACH} pixels around the lit point that a "
                             f"white database keeps: fit rings up to r = {REACH}")
    rings = len(measured.radii)
    wanted = settings.layers or (len(settings.boundaries) + 1 if settings.boundaries is not None else 1)
    if rings <= wanted:
        raise InversionError(f"the profile holds {rings} ring(s); fitting {wanted} layer(s) needs more rings than "
                             f"layers in each channel: use a dataset of larger max_radius or fewer layers")
    mus_choices = [settings.mus] if settings.mus is not None else list(MUS_GRID)
    # Every refractive index tried goes with every scattering: the index changes how much light the
    # surface sends back in and so the profile's shape, as the scattering does.
    choices = [(n, mus) for n in settings.indices for mus in mus_choices]
    candidates = []
    # The records each database's quick fits use, by its optics: a search keeps a quarter of each
    # database's photons (it held every database whole: 3.0 GB of peak RSS searching layers3); the
    # few it fits fully get white runs of their own, tallied in cells.
    searched: dict[SlabOptics, WhiteDatabase] = {}

    def keep(database: WhiteDatabase) -> None:
        searched[database.optics] = (_thinned(database, SEARCH_SHARE) if settings.boundaries is None
                                     else database)

    def try_structures(trials, first: float, what: str, span: float | None = None) -> None:
        """Quick fits of ``trials``, (structure, optics, mus) each, added to the candidates, the
        progress going from ``first`` over ``span`` (default: a share); each database is made (or
        loaded) when first needed."""
        span = share if span is None else span
        for number, (structure, optics, mus) in enumerate(trials):
            report(first + span * number / len(trials), what)
            if optics not in searched:
                report(first + span * number / len(trials), f"white Monte Carlo for {_optics_text(optics, mus)}")
                keep(white_database(optics, settings.photons, device=device))
            forward = Forward(searched[optics], structure, measured.radii, ring_weights=measured.ring_weights)
            fits = fit_channels(forward, measured.mean, measured.standard_error, intervals=False, floor=measured.floor)
            chi2 = sum(f.chi2 for f in fits)
            candidates.append(Candidate(bic(chi2, sum(f.used for f in fits), structure, mus), chi2, mus,
                                        structure, optics))

    bins = database_optics(settings, mus_choices[0], choices[0][0]).bins
    structures = list(all_structures(settings, bins, rings - 1))
    base_search = settings.mus is None and any(structure.layers > 1 for structure in structures)
    refine = len(REFINE_STEPS) if settings.mus is None else 0  # a share for each step
    screening = len(structures) > 1 or len(choices) > 1  # more than one model: screened with every photon
    share = 1.0 / (len(choices) + 2 + base_search + refine + screening)
    for index, (n, mus) in enumerate(choices):
        optics = database_optics(settings, mus, n)
        if len(structures) == 1 and len(choices) == 1:
            # Nothing to compare: the one model is fitted with a white run of its own below, and
            # the search's database (14-43 MB to read) is not needed.
            candidates.append(Candidate(0.0, 0.0, mus, structures[0], optics))
            break
        what = f"white Monte Carlo for {_optics_text(optics, mus)}"
        report(index * share, what)
        keep(white_database(optics, settings.photons, device=device,
                            progress=lambda fraction: report((index + 0.5 * fraction) * share, what)))
        # With several scatterings (or indices) to try, each is scouted on the structures with even
        # boundaries; the others are tried for the best one only.
        scouts = scout_structures(structures) if len(choices) > 1 else structures
        try_structures([(structure, optics, mus) for structure in scouts], (index + 0.5) * share,
                       f"fitting structures for {_optics_text(optics, mus)}")
    if len(choices) > 1 and (scouted := best_candidate(candidates)):
        _, _, mus, _, optics = scouted
        rest = [structure for structure in structures if structure not in scout_structures(structures)]
        try_structures([(structure, optics, mus) for structure in rest], len(choices) * share,
                       f"fitting every structure for {_optics_text(optics, mus)}")
    if base_search and (leading := best_candidate(candidates)):
        # A base of its own scattering is tried for the layer count and index that fitted best (two
        # layers at least), on databases of its own: those of the phases before are let go (a
        # phase that needs one again reads it from the cache).
        searched.clear()
        count = max(leading.structure.layers, 2)
        search_base(settings, leading.optics.n, [structure for structure in structures if structure.layers == count],
                     candidates, try_structures, lambda fraction: (len(choices) + 1 + fraction) * share)
    if refine and (leading := best_candidate(candidates)):
        searched.clear()
        refine_scattering(settings, leading, bins, candidates, try_structures, (len(choices) + 1 + base_search) * share,
                           share)
    best = best_candidate(candidates)
    if best is None:
        raise InversionError("too few rings stand out of the noise (E >= 3 sigma) to fit these layers")
    usable = [c for c in candidates if math.isfinite(c.bic)]
    # Structures and scatterings that fit about as well are as plausible as the best: each layer's
    # region spans theirs too, so the choice of model is part of its uncertainty.
    rivals = sorted((c for c in usable if c.structure.layers == best.structure.layers
                     and (c.structure, c.optics) != (best.structure, best.optics)), key=lambda c: c.chi2)
    rivals = [c for c in rivals if c.chi2 - best.chi2 <= PLAUSIBLE_CHI2][:MAX_RIVALS]
    searched.clear()  # the structures fitted at the end get white runs of their own
    screened = []
    if screening:
        # The quick fits' own noise can rank neighbouring structures wrongly: the choice, its rivals
        # and its boundary neighbours are ranked again with every photon (:mod:`.finalists`).
        screened = screen(settings, [best, *rivals], bins, measured, report,
                          (len(choices) + 1 + base_search + refine) * share, share, device)
        best = screened[0]
        rivals = [c for c in screened[1:] if c.structure.layers == best.structure.layers
                  and c.chi2 - best.chi2 <= PLAUSIBLE_CHI2][:MAX_RIVALS]
    fitted = []
    for number, candidate in enumerate([best, *rivals]):
        done = (len(choices) + 1 + base_search + refine + screening + number / (len(rivals) + 1)) * share
        what = (f"white Monte Carlo of {settings.final_photons} photons for "
                f"{'the chosen structure' if not number else 'a structure that fits as well'}")
        report(done, what)
        cells = cell_database(candidate.optics, candidate.structure, settings.final_photons, device=device,
                              progress=lambda fraction: report(done + 0.5 * fraction * share / (len(rivals) + 1), what))
        report(done + 0.5 * share / (len(rivals) + 1),
               "fitting the chosen structure" if not number else "fitting the structures that fit as well")
        forward = CellForward(cells, candidate.structure, measured.radii, ring_weights=measured.ring_weights)
        fits = fit_channels(forward, measured.mean, measured.standard_error, floor=measured.floor)
        fitted.append(Fitted(candidate, fits, fit_jointly(forward, measured.mean, measured.standard_error, fits,
                                                          measured.floor, measured.covariance),
                             forward))
    # The search compared quick fits on thinned databases, each with noise of its own: of the
    # chosen one and its rivals, the one that fits best with every photon is reported, by the joint
    # fits' chi-square when every one has one (it weighs the noise common to the channels as such).
    together = all(fit.joint is not None for fit in fitted)
    chosen = min(fitted, key=lambda fit: bic(*fit.misfit(together), fit.candidate.structure, fit.candidate.mus))
    (_, _, mus, structure, optics), fits, joint, forward = chosen
    if all(fit.used <= structure.layers for fit in fits):
        raise InversionError(f"no channel has more rings than layers that stand out of the noise (E >= 3 sigma) "
                             f"and that the white run's {forward.database.photons} photons reach: use a larger region, "
                             f"fewer layers or more photons")
    layers = layer_colours(fits, structure, optics, colorspace, joint)
    for other in fitted:
        if other is not chosen:
            layers = [widened(layer, widening) for layer, widening in zip(layers, layer_colours(
                other.fits, other.candidate.structure, other.candidate.optics, colorspace, other.joint))]
    fitted_mua = joint.mua if joint is not None else np.array([f.mua for f in fits])
    limits = data_limits(forward, fitted_mua, measured.mean, measured.standard_error, np.array([f.used for f in fits]),
                         colorspace, joint.floor_correlation if joint is not None else 0.0, measured.floor,
                         measured.covariance, np.array([layer.xy for layer in layers]),
                         exact_regions(forward, measured.mean, measured.standard_error, colorspace, measured.floor, fits))
    # A region is never narrower than what the data alone allow (where that is quadratic).
    layers = [replace(layer, region=joined(layer.region, limit.ellipse), allowed_width=limit.width,
                      limit=limit_reason(limit.width)) for layer, limit in zip(layers, limits)]
    if joint is not None:
        chi2, dof, model, sigma = joint.chi2, joint.dof, joint.model, joint.sigma
    else:
        chi2, dof = float(sum(f.chi2 for f in fits)), int(sum(f.dof for f in fits))
        model, sigma = np.stack([f.model for f in fits], axis=1), np.stack([f.sigma for f in fits], axis=1)
    from scipy.stats import chi2 as chi2_distribution  # imported here, as scipy.optimize in .fit

    warning = None
    if dof and chi2_distribution.sf(chi2, dof) < MISFIT_P:
        warning = (f"the model does not fit: chi-square {chi2:.0f} for {dof} degrees of freedom "
                   f"(check n, g, the scattering, the layer count and whether the region is laterally uniform)")
        layers = [replace(layer, determined=False, reason="the model does not fit the profile (chi-square), so its "
                          "uncertainty regions do not hold") for layer in layers]
    searched_mus = (f" (chosen from {', '.join(map(str, MUS_GRID))}, common or with a base of its own, and refined "
                    "between them)")
    searched_n = f" (chosen from {', '.join(f'{n:g}' for n in N_GRID)} by chi-square)"
    other_indices = sorted({fit.candidate.optics.n for fit in fitted} - {optics.n})
    notes = (f"{structure.layers} layer(s), boundaries {list(structure.starts[1:]) or 'none'}"
             f"{' (searched)' if settings.boundaries is None else ''}, mus {_mus_text(mus)}"
             f"{searched_mus if settings.mus is None else ''}"
             f"{' (assumes every layer scatters alike)' if not isinstance(mus, tuple) and structure.layers > 1 else ''}, "
             f"n {optics.n:g}{searched_n if settings.n is None else ''}, g {optics.g:g}, {forward.database.photons} white "
             f"photons"
             + (f" (the search's {settings.photons} each"
                + (f"; {len(screened)} model(s) ranked again with every photon" if screened else "") + ")"
                if screening else "")
             + f" on {device.name}"
             + (f"; regions also span {len(rivals)} other model(s) within chi-square {PLAUSIBLE_CHI2:g} of it"
                + (f" (n {', '.join(f'{n:g}' for n in other_indices)} among them)" if other_indices else "")
                if rivals else "")
             + (f"; channels fitted together (floor correlated {joint.floor_correlation:g} between them)"
                if joint is not None else "; channels fitted one by one (the joint fit "
                "needs every channel's own fit)")
             + (f"; data noise: the spread of its {measured.replicates} replicates (noise the lit points share "
                "included), no floor" if measured.replicates > 1 else
                f"; data noise: the spread of the region's lit points' rings, with a {measured.floor:.0%} floor for "
                "noise the lit points share (the dataset holds no replicates to measure it)"))
    report(1.0, "done")
    return Inversion(layers, measured, model, sigma, np.array([f.used for f in fits]), chi2, dof, warning, notes,
                     time.perf_counter() - start)


def _mus_text(mus) -> str:
    return ", ".join(f"{m:g}" for m in np.atleast_1d(mus))


def _optics_text(optics: SlabOptics, mus) -> str:
    return f"mus {_mus_text(mus)}, n {optics.n:g}"


def _thinned(database, share: int):
    """The records of the first 1/share of the photons, as a database of that many photons."""
    keep = database.photon < database.photons // share
    return WhiteDatabase(database.optics, database.photons // share, database.pixel[keep], database.value[keep],
                         database.lengths[keep], database.photon[keep], database.seconds)
