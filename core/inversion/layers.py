"""Layer colours by inversion: fit a layered slab to a region's ring-light profiles.

The model (:mod:`.forward`, :mod:`.white_mc`): layers of a common or given scattering
coefficient, each with its own absorption per channel, index ``n`` and anisotropy ``g`` given.
The structure (layer boundaries, whole grid steps down to :data:`SEARCH_BINS` - 1) is given or
searched by chi-square; the number of layers is given or chosen by BIC. The scattering is given
(common or per layer) or chosen from :data:`MUS_GRID`: common to every layer, or one for the layers
above and another for the base (:func:`_base_search`), by BIC. Each layer's colour is what
FORMAT.md defines as the truth: the thick-slab reflectance of its fitted material (adding-doubling),
with a two-sigma region in xy (:mod:`.fit`): the chromaticities of every combination of per-channel
reflectances within the channels' intervals (a convex polygon: the image of a box in RGB).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np
from scipy.stats import chi2 as chi2_distribution

from ..colour.chroma import chromaticity, srgb_swatch
from ..simulate.adding_doubling import thick_slab_reflectance
from .fit import JOINT_CHI2, MUA_BOUNDS, ChannelFit, fit_channels
from .forward import Forward, Structure
from .measured import MeasuredProfile
from .settings import MAX_LAYERS, MUS_GRID, SEARCH_BINS, InversionError, InversionSettings
from .white_mc import SlabOptics, WhiteDatabase, white_database

SEARCH_SHARE = 4
"""A structure search fits with one in this many of the database's photons; the chosen one is
fitted again with all."""
CHANNEL_NAMES = ("R", "G", "B")
PLAUSIBLE_CHI2 = JOINT_CHI2
"""Structures (and common scatterings) whose search chi-square is within this of the chosen one's
are fitted too, and each layer's region spans theirs (the same threshold as a layer's region)."""
MAX_RIVALS = 4
"""At most this many of them (the best-fitting), to bound the time."""
REACH = 13
"""Pixels from the lit point (in y and in x) that a white database keeps."""
MISFIT_P = 1e-3
"""A fit whose chi-square is this improbable under the model is reported as not fitting, and none
of its layers as determined."""


@dataclass(frozen=True)
class InvertedLayer:
    """One fitted layer.

    Attributes
    ----------
    top, bottom
        Depth range, grid steps.
    mus
        Scattering coefficient, per grid step.
    mua, mua_interval
        (3,) fitted absorption and (3, 2) its two-sigma range per channel, per grid step.
    determined
        False when some channel's absorption is not bounded by the data; ``reason`` says which.
    rgb, xy
        Thick-slab colour (linear, the dataset's colourspace) and its chromaticity.
    region
        (K, 2) the two-sigma region in xy, a convex polygon.
    swatch
        8-bit sRGB of ``rgb``.
    """

    top: float
    bottom: float
    mus: float
    mua: np.ndarray
    mua_interval: np.ndarray
    determined: bool
    reason: str
    rgb: np.ndarray
    xy: np.ndarray
    region: np.ndarray
    swatch: tuple[int, int, int]

    @property
    def region_width(self) -> float:
        """The two-sigma region's larger extent in x or y (NaN without a region)."""
        return float(np.ptp(self.region, axis=0).max()) if len(self.region) else float("nan")


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


class Candidate(NamedTuple):
    """One structure tried in a search: its BIC and chi-square (quick fit), scattering, database."""

    bic: float
    chi2: float
    mus: float | tuple[float, ...]
    structure: Structure
    database: WhiteDatabase


def invert(measured: MeasuredProfile, settings: InversionSettings, colorspace: str = "sRGB",
           progress: Progress | None = None) -> Inversion:
    """Fit ``measured`` (R, 3) as ``settings`` say; ``progress(fraction, what)`` is called along
    the way (raise from it to cancel)."""
    settings.check()
    start = time.perf_counter()
    report = progress or (lambda fraction, what: None)
    if not np.isfinite(measured.mean).any():
        raise InversionError("the region's profile holds no values")
    mus_choices = [settings.mus] if settings.mus is not None else list(MUS_GRID)
    candidates = []
    searched = {}  # id of a database -> the records its quick fits use

    def try_structures(trials, first: float, what: str) -> None:
        """Quick fits of ``trials``, (structure, database, mus) each, added to the candidates."""
        for number, (structure, database, mus) in enumerate(trials):
            report(first + share * number / len(trials), what)
            if id(database) not in searched:
                searched[id(database)] = (_thinned(database, SEARCH_SHARE) if settings.boundaries is None
                                          else database)
            search = searched[id(database)]
            forward = Forward(search, structure, measured.radii, ring_weights=measured.ring_weights)
            fits = fit_channels(forward, measured.mean, measured.standard_error, intervals=False)
            chi2 = sum(f.chi2 for f in fits)
            candidates.append(Candidate(_bic(chi2, sum(f.used for f in fits), structure, mus), chi2, mus,
                                        structure, database))

    databases = {}
    structures = list(_structures(settings, database_optics(settings, mus_choices[0]).bins))
    base_search = settings.mus is None and any(structure.layers > 1 for structure in structures)
    share = 1.0 / (len(mus_choices) + 2 + base_search)
    for index, mus in enumerate(mus_choices):
        what = f"white Monte Carlo for mus {_mus_text(mus)}"
        report(index * share, what)
        optics = database_optics(settings, mus)
        databases[index] = white_database(optics, settings.photons,
                                          progress=lambda fraction: report((index + 0.5 * fraction) * share, what))
        if len(structures) == 1 and len(mus_choices) == 1:
            candidates.append(Candidate(0.0, 0.0, mus, structures[0], databases[index]))
            break
        # With several scatterings to try, each is scouted on the structures with even boundaries;
        # the others are tried for the best scattering only.
        scouts = _scouts(structures) if len(mus_choices) > 1 else structures
        try_structures([(structure, databases[index], mus) for structure in scouts], (index + 0.5) * share,
                       f"fitting structures for mus {_mus_text(mus)}")
    if len(mus_choices) > 1 and (scouted := _best(candidates)):
        _, _, mus, _, database = scouted
        rest = [structure for structure in structures if structure not in _scouts(structures)]
        try_structures([(structure, database, mus) for structure in rest], len(mus_choices) * share,
                       f"fitting every structure for mus {_mus_text(mus)}")
    if base_search and (leading := _best(candidates)):
        # A base of its own scattering is tried for the layer count that fitted best (two at least).
        count = max(leading.structure.layers, 2)
        _base_search(settings, [structure for structure in structures if structure.layers == count], candidates,
                     try_structures, lambda fraction: (len(mus_choices) + 1 + fraction) * share, report)
    best = _best(candidates)
    if best is None:
        raise InversionError("too few rings stand out of the noise (E >= 3 sigma) to fit these layers")
    usable = [c for c in candidates if math.isfinite(c.bic)]
    # Structures and scatterings that fit about as well are as plausible as the best: each layer's
    # region spans theirs too, so the choice of model is part of its uncertainty.
    rivals = sorted((c for c in usable if c.structure.layers == best.structure.layers
                     and (c.structure != best.structure or c.mus != best.mus)), key=lambda c: c.chi2)
    rivals = [c for c in rivals if c.chi2 - best.chi2 <= PLAUSIBLE_CHI2][:MAX_RIVALS]
    fitted = []
    for number, candidate in enumerate([best, *rivals]):
        report((len(mus_choices) + 1 + base_search + number / (len(rivals) + 1)) * share,
               "fitting the chosen structure" if not number else "fitting the structures that fit as well")
        forward = Forward(candidate.database, candidate.structure, measured.radii,
                          ring_weights=measured.ring_weights)
        fitted.append((candidate, fit_channels(forward, measured.mean, measured.standard_error)))
    # The search compared quick fits on thinned databases, each with noise of its own: of the
    # chosen one and its rivals, the one that fits best with every photon is reported.
    (_, _, mus, structure, database), fits = min(fitted, key=lambda pair: _bic(
        sum(f.chi2 for f in pair[1]), sum(f.used for f in pair[1]), pair[0].structure, pair[0].mus))
    layers = _layers(fits, structure, database.optics, colorspace)
    for other, other_fits in fitted:
        if other.structure != structure or other.mus != mus:
            layers = [_widened(layer, widening) for layer, widening in
                      zip(layers, _layers(other_fits, other.structure, other.database.optics, colorspace))]
    chi2 = float(sum(f.chi2 for f in fits))
    dof = int(sum(f.dof for f in fits))
    warning = None
    if dof and chi2_distribution.sf(chi2, dof) < MISFIT_P:
        warning = (f"the model does not fit: chi-square {chi2:.0f} for {dof} degrees of freedom "
                   f"(check n, g, the scattering, the layer count and whether the region is laterally uniform)")
        layers = [replace(layer, determined=False, reason="the model does not fit the profile (chi-square), so its "
                          "uncertainty regions do not hold") for layer in layers]
    searched_mus = f" (chosen from {', '.join(map(str, MUS_GRID))}, common or with a base of its own)"
    notes = (f"{structure.layers} layer(s), boundaries {list(structure.starts[1:]) or 'none'}"
             f"{' (searched)' if settings.boundaries is None else ''}, mus {_mus_text(mus)}"
             f"{searched_mus if settings.mus is None else ''}"
             f"{' (assumes every layer scatters alike)' if not isinstance(mus, tuple) and structure.layers > 1 else ''}, "
             f"n {settings.n:g}, g {settings.g:g}, {database.photons} white photons"
             + (f"; regions also span {len(rivals)} other structure(s) within chi-square {PLAUSIBLE_CHI2:g} of it"
                if rivals else ""))
    report(1.0, "done")
    return Inversion(layers, measured, np.stack([f.model for f in fits], axis=1),
                     np.stack([f.sigma for f in fits], axis=1), np.array([f.used for f in fits]), chi2, dof,
                     warning, notes, time.perf_counter() - start)


def _best(candidates: list[Candidate]) -> Candidate | None:
    """The candidate of lowest BIC, or None when no fit succeeded."""
    return min((c for c in candidates if math.isfinite(c.bic)), key=lambda c: c.bic, default=None)


def _bic(chi2: float, points: int, structure: Structure, mus) -> float:
    """The Bayesian information criterion of a fit of ``points`` rings (every channel's): each
    channel's absorption per layer is an unknown, and a base with a scattering of its own
    (``mus`` a tuple) one more; infinite for a fit that failed."""
    unknowns = 3 * structure.layers + (1 if isinstance(mus, tuple) else 0)
    return chi2 + unknowns * math.log(max(points, 1)) if math.isfinite(chi2) else math.inf


def _base_search(settings: InversionSettings, structures: list[Structure], candidates: list[Candidate],
                 try_structures, fraction_done: Callable[[float], float], report: Progress) -> None:
    """Try structures of two or more layers again with a base that scatters otherwise than the
    layers above: every pair of scatterings of :data:`MUS_GRID` on those of ``structures`` with even
    boundaries, then every other one with the pair that fitted best. A thin upper layer over a base
    that scatters otherwise (skin over flesh) is the common case; one scattering for all may then
    fit a wrong structure as well as the right one, with regions that leave out the truth, or fit
    none. ``try_structures`` adds its quick fits to ``candidates``."""
    databases: dict[tuple[float, float, int], WhiteDatabase] = {}

    def trial(structure: Structure, common: float, base: float):
        key = (common, base, structure.starts[-1])
        if key not in databases:
            report(fraction_done(0.0), f"white Monte Carlo for mus {common:g} over a base of {base:g}")
            databases[key] = white_database(_base_optics(settings, common, base, structure.starts[-1]),
                                            settings.photons)
        return structure, databases[key], (common,) * (structure.layers - 1) + (base,)

    scouts = _scouts([structure for structure in structures if structure.layers > 1])
    first = len(candidates)
    try_structures([trial(structure, common, base) for common in MUS_GRID for base in MUS_GRID if base != common
                    for structure in scouts], fraction_done(0.0),
                   "fitting structures with a base that scatters otherwise")
    chosen = _best(candidates[first:])
    if chosen is None:
        return
    common, base = chosen.mus[0], chosen.mus[-1]
    rest = [structure for structure in structures if structure.layers > 1 and structure not in scouts]
    try_structures([trial(structure, common, base) for structure in rest], fraction_done(0.5),
                   f"fitting every structure with mus {common:g} over a base of {base:g}")


def _widened(layer: InvertedLayer, other: InvertedLayer) -> InvertedLayer:
    """``layer`` with its region and absorption ranges grown to cover ``other`` (the same layer in
    a rival structure); determined only if both are."""
    points = np.vstack([layer.region, other.region, layer.xy[None], other.xy[None]]).astype(np.float32)
    points = points[np.isfinite(points).all(axis=1)]
    region = cv2.convexHull(points).reshape(-1, 2).astype(np.float64) if len(points) else layer.region
    interval = np.stack([np.minimum(layer.mua_interval[:, 0], other.mua_interval[:, 0]),
                         np.maximum(layer.mua_interval[:, 1], other.mua_interval[:, 1])], axis=1)
    determined = layer.determined and other.determined
    reason = layer.reason or other.reason
    if not determined and not reason:
        reason = "not determined under a structure that fits as well"
    return replace(layer, region=region, mua_interval=interval, determined=determined, reason=reason)


def _mus_text(mus) -> str:
    return ", ".join(f"{m:g}" for m in np.atleast_1d(mus))


def database_optics(settings: InversionSettings, mus) -> SlabOptics:
    """The white database's optics: per-layer scattering over the given boundaries, or a common
    one over :data:`SEARCH_BINS` bins."""
    if isinstance(mus, tuple):
        edges = [0, *settings.boundaries]
        bins = []
        for k, top in enumerate(edges):
            bottom = edges[k + 1] if k + 1 < len(edges) else top + 1
            bins += [mus[k]] * (bottom - top)
        return _optics(settings, bins)
    return _optics(settings, [mus] * SEARCH_BINS)


def _base_optics(settings: InversionSettings, common: float, base: float, top: int) -> SlabOptics:
    """A database's optics for a structure whose base, from bin ``top`` down, scatters with ``base``
    and every bin above with ``common``."""
    return _optics(settings, [common if b < top else base for b in range(max(SEARCH_BINS, top + 1))])


def _optics(settings: InversionSettings, bins) -> SlabOptics:
    """Optics of scattering ``bins`` per depth bin, with ``settings``' g, n and depth."""
    return SlabOptics(tuple(float(m) for m in bins), settings.g, settings.n, settings.depth, REACH)


def _structures(settings: InversionSettings, bins: int):
    """Every structure to try."""
    if settings.boundaries is not None:
        yield Structure((0, *settings.boundaries))
        return
    counts = [settings.layers] if settings.layers is not None else range(1, MAX_LAYERS + 1)
    for count in counts:
        for cut in itertools.combinations(range(1, bins), count - 1):
            yield Structure((0, *cut))


def _scouts(structures: list[Structure]) -> list[Structure]:
    """The structures whose boundaries all lie at even depths (all of them if none does)."""
    even = [structure for structure in structures if all(b % 2 == 0 for b in structure.starts[1:])]
    return even or structures


def _thinned(database, share: int):
    """The records of the first 1/share of the photons, as a database of that many photons."""
    keep = database.photon < database.photons // share
    return WhiteDatabase(database.optics, database.photons // share, database.pixel[keep], database.value[keep],
                         database.lengths[keep], database.photon[keep], database.seconds)


def _layers(fits: list[ChannelFit], structure: Structure, optics: SlabOptics, colorspace: str) -> list[InvertedLayer]:
    ranges = structure.depth_ranges(optics.depth)
    layers = []
    for k, (top, bottom) in enumerate(ranges):
        mus = optics.mus[structure.starts[k]]
        mua = np.array([f.mua[k] for f in fits])
        interval = np.array([f.interval[k] for f in fits])
        open_channels = [CHANNEL_NAMES[c] for c, f in enumerate(fits) if f.unbounded[k] or not np.isfinite(f.mua[k])]
        reason = ""
        if open_channels:
            reason = (f"absorption in {', '.join(open_channels)} is not bounded by the data (the two-sigma range "
                      f"reaches {MUA_BOUNDS[1]:g} per grid step): the layers above absorb that light, or too "
                      f"few rings stand out of the noise")
        filled = np.where(np.isfinite(mua), mua, MUA_BOUNDS[1])
        rgb = thick_slab_reflectance(np.full(3, mus), filled, optics.g, optics.n)
        corners = np.array(list(itertools.product(*[interval[c] for c in range(3)])))  # (8, 3) mua
        corner_rgb = thick_slab_reflectance(np.full(corners.size, mus), corners.ravel(), optics.g,
                                            optics.n).reshape(corners.shape)
        corner_xy = chromaticity(corner_rgb, colorspace)
        corner_xy = corner_xy[np.isfinite(corner_xy).all(axis=1)]
        region = cv2.convexHull(corner_xy.astype(np.float32)).reshape(-1, 2).astype(np.float64) \
            if len(corner_xy) else np.zeros((0, 2))
        layers.append(InvertedLayer(top, bottom, float(mus), mua, interval, not open_channels, reason, rgb,
                                    chromaticity(rgb, colorspace), region, srgb_swatch(rgb, colorspace)))
    return layers


def region_contains(region: np.ndarray, xy) -> bool:
    """Whether the polygon ``region`` (K, 2) contains ``xy`` (on the edge counts)."""
    if len(region) < 3:
        return False
    return cv2.pointPolygonTest(region.astype(np.float32).reshape(-1, 1, 2), (float(xy[0]), float(xy[1])),
                                False) >= 0
