"""Maps of absorption mu_a and reduced scattering mu_s' per pixel and channel: each pixel's ring
profile E_p(r) fitted as a homogeneous semi-infinite medium (:mod:`.pixel_fit` on :mod:`.table`).

The profile is the ring light stack at radii 0, 1, ... (thickness 1, every ring within the
dataset's max_radius), its standard errors the noise of the stack (:mod:`ringlight.core.rings.noise`:
the replicates' spread where the dataset holds replicates, else the spread of each ring's members,
computed with the stack in one pass over the responses, :mod:`ringlight.core.rings.stack_spread`).
Ring 0 has one member, so no spread: its standard error is the relative error of the nearest ring
that has one, scaled by the square root of their member counts (independent members of equal
relative noise). A relative :data:`MODEL_FLOOR` is added to every ring for what the noise does not
show (the table's own Monte Carlo noise, a rig's calibration): :mod:`.ring_sigma`, made by each fit.

Each pixel is fitted by Gauss-Newton steps from a finer table's nodes (:mod:`.node_fit`), within
0.012 (the benchmark's map) to 0.014 (simulated slabs) of a standard error of the full
Levenberg-Marquardt fit on the table's splines (:mod:`.pixel_fit`, ``estimator="full"``), which
fits the steps do not settle and region fits use. Without replicates, a stack or errors given,
pixels are fitted as soon as their rings and their spread are stacked, 64 of a row at a time
(:mod:`.one_pass`, their fits as the lanes of vectorised loops: :mod:`.chunk_fit`): no
(R, H, W, 3) stack or errors are written.

Cost (``benchmarks/bench_optics.py --repeats 7``, 800 x 800, max_radius 8, a two-core machine):
the map beyond the stack, the median over a run's rounds, 0.75-0.88 x the stack; the node fits
0.07-0.09 us CPU each (docs/guide/optics.md, Speed).

A pixel whose rings are cut by the grid's edge (or by unlit points) is fitted with the whole
rings' model and flagged (:attr:`OpticalMaps.complete` False): on a homogeneous surface a cut
ring's members are a biased subset of distances. A pixel's values are those of the medium its
rings see: across an edge between two materials they come within 1 % (mu_s') and 3 % (mu_a) of each material's own at
about max_radius from the edge, and mu_s' steps from 10 % to 90 % within 3 grid steps
(``tools/evaluate_optics.py --scenes``, max_radius 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..errors import Cancelled, RinglightError
from ..phases import phase
from ..rings.geometry import ring_geometry
from ..rings.noise import luminance_weights, stack_noise
from ..rings.replicate_noise import replicate_spread
from ..rings.stack_spread import ring_stack_and_errors
from ..rings.stacks import Stack, ring_stack
from . import one_pass
from .pixel_fit import CONVERGED, fit_profiles, fits_compiled
from .table import DEFAULT_PHOTONS, ProfileTable, check_photons, table_for

MODEL_FLOOR = 0.005
"""Relative standard deviation added to every ring's: the table's own noise (at its default
10^6 photons, 0.03-0.3 % per ring, from four independent runs) and what else the model leaves out."""
FIRST_RUN = " (first run after an install or update: compiling them, about half a minute)"
"""Said after the fits' phase where numba's cache lacks their kernel: the bar stays where it is
meanwhile (a 40 x 40 map's first run compiled for 32 s on a two-core machine)."""
DETERMINED_RELATIVE_ERROR = 0.5
"""A value is *determined* where its fit converged inside the table and its standard error is
below this fraction of it."""
CHANNELS = ("R", "G", "B")


class OpticsError(RinglightError):
    """Optical properties asked of a dataset (or with arguments) that cannot give them."""


@dataclass(frozen=True, eq=False)
class OpticalMaps:
    """Per-pixel optical properties of a homogeneous half-space fitted to each pixel's E(r).

    Attributes
    ----------
    mua, musp
        (H, W, C) float32 absorption and reduced scattering coefficients, in ``units``; NaN where
        no fit was possible.
    mua_se, musp_se
        (H, W, C) float32 their standard errors (linearised fit).
    determined
        (H, W, C) bool: the fit converged inside the table and both relative standard errors are
        below :data:`DETERMINED_RELATIVE_ERROR` (mua_determined, musp_determined say which).
    mua_determined, musp_determined
        (H, W, C) bool per property.
    chi2
        (H, W, C) float32 the fit's chi-square over ``rings`` (H, W, C) int32 rings used.
    complete
        (H, W) bool: every ring of the profile lies whole on the grid and lit (else the fit is biased).
    units
        ``"per_mm"`` (the manifest gives ``grid.pitch_mm``) or ``"per_grid_step"``.
    pitch_mm
        The pitch behind per-mm units, else None.
    n, g
        Refractive index and anisotropy assumed.
    channels
        Channel names, ``("R", "G", "B")``.
    radii
        (R,) ring radii fitted, grid steps.
    noise_source
        ``"replicates"`` or ``"ring spread"``: where the standard errors of E_r came from.
    scale
        (C,) the rig's scale the model was multiplied by (1 for a simulated dataset).
    """

    mua: np.ndarray
    musp: np.ndarray
    mua_se: np.ndarray
    musp_se: np.ndarray
    determined: np.ndarray
    mua_determined: np.ndarray
    musp_determined: np.ndarray
    chi2: np.ndarray
    rings: np.ndarray
    complete: np.ndarray
    units: str
    pitch_mm: float | None
    n: float
    g: float
    channels: tuple[str, ...]
    radii: np.ndarray
    noise_source: str
    scale: np.ndarray


def profile_radii(dataset: ImpulseDataset, thickness: float = 1.0) -> np.ndarray:
    """Radii 0, 1, ... (grid steps) of every ring of ``thickness`` within the dataset's max_radius."""
    last = math.floor(dataset.max_radius - thickness / 2.0 + 1e-9)
    if last < 2:
        raise OpticsError(f"{dataset.path}: max_radius {dataset.max_radius:g} holds fewer than 3 rings; "
                          f"optical properties need rings 0, 1, 2 at least")
    return np.arange(0.0, last + 1.0)


def sample_optics(dataset: ImpulseDataset, n: float | None, g: float | None) -> tuple[float, float]:
    """``n`` and ``g`` as given, else as the manifest's ``sample`` key states them; OpticsError
    naming the dataset when neither gives ``n`` (``g`` defaults to 0, isotropic scattering)."""
    sample = dataset.manifest.sample
    n = n if n is not None else sample.n
    g = g if g is not None else (sample.g if sample.g is not None else 0.0)
    if n is None:
        raise OpticsError(f"{dataset.path}: the manifest states no refractive index (sample.n); give n "
                          f"(--n), e.g. 1.4 for tissue")
    if not 1.0 <= n <= 3.0:
        raise OpticsError(f"refractive index n must lie in [1, 3], got {n:g}")
    if not -0.95 <= g <= 0.95:
        raise OpticsError(f"anisotropy g must lie in [-0.95, 0.95], got {g:g}")
    return float(n), float(g)


def error_freedom(dataset: ImpulseDataset, radii: np.ndarray, noise_source: str) -> np.ndarray:
    """(R,) degrees of freedom of each ring's standard error: replicates - 1, or for the ring
    spread its members less its groups of equal distance (:mod:`ringlight.core.rings.noise`, whole
    rings); a ring without a spread (r = 0) borrows its neighbour's."""
    if noise_source == "replicates":
        return np.full(len(radii), len(dataset.manifest.replicates) - 1.0)
    freedom = []
    for radius in radii:
        offsets = ring_geometry(float(radius)).offsets
        distances = np.unique(offsets[:, 0] ** 2 + offsets[:, 1] ** 2)
        freedom.append(float(len(offsets) - len(distances)))
    freedom = np.asarray(freedom)
    spread = np.flatnonzero(freedom > 0)
    return freedom if not len(spread) else np.where(freedom > 0, freedom, freedom[spread[0]])


def t_inflation(freedom: np.ndarray) -> np.ndarray:
    """(R,) factors for standard errors estimated with ``freedom`` degrees of freedom: a residual
    over such an error is Student-t distributed, of variance nu / (nu - 2) (sqrt(3) for nu <= 3),
    so the fit weighs the ring as the variance it has; at r = 1 (8 members at 2 distances, nu = 6)
    the factor is 1.22. Without it, two-sigma intervals held the truth in 93.5 % of pixels on the
    maps' own model at 5 % noise per response (tests/test_optics_maps.py), 95 % with it."""
    return np.sqrt(np.where(freedom > 3, freedom / np.maximum(freedom - 2.0, 1e-9), 3.0))


def ring_errors(dataset: ImpulseDataset, radii: np.ndarray, progress=None) -> tuple[np.ndarray, str]:
    """(R, H, W, 3) float32 standard errors of E_r at ``radii`` 0, 1, ... (thickness 1) and where
    they come from: the replicates' spread (:mod:`ringlight.core.rings.replicate_noise`) or the
    ring members' spread (:func:`ringlight.core.rings.noise.stack_noise`, whose transient errors
    ``sqrt(SE(E_r)^2 + SE(E_{r+1})^2)`` give the last ring's, since its own ring r + 1 lies beyond
    max_radius)."""
    if len(dataset.manifest.replicates) > 1:
        every = np.arange(len(radii))
        ring, _, _, _ = replicate_spread(dataset, radii, every, every, 1.0, False,
                                         luminance_weights(dataset.colorspace), progress)
        return ring, "replicates"
    noise = stack_noise(dataset, radii[:-1], 1.0, progress=progress)
    last = np.sqrt(np.maximum(noise.transient[-1] ** 2 - noise.ring[-1] ** 2, 0.0))
    return np.concatenate([noise.ring, last[None]]), "ring spread"


def optical_maps(dataset: ImpulseDataset, *, n: float | None = None, g: float | None = None, calibration=None,
                 progress=None, cancelled=None, stack: Stack | None = None, errors: np.ndarray | None = None,
                 noise_source: str | None = None, photons: int = DEFAULT_PHOTONS,
                 floor: float = MODEL_FLOOR, estimator: str = "nodes") -> OpticalMaps:
    """mu_a and mu_s' (and their standard errors) of every pixel and channel of ``dataset``.

    Parameters
    ----------
    dataset
        An open impulse dataset.
    n, g
        Refractive index and Henyey-Greenstein anisotropy; None takes the manifest's ``sample``.
    calibration
        A :class:`ringlight.core.optics.calibration.Calibration` for a real rig (its per-channel scale); None for a
        simulated, absolute dataset.
    progress
        ``progress(fraction)`` along the way (may raise :class:`~ringlight.core.errors.Cancelled`).
    cancelled
        ``cancelled() -> bool`` asked along the way; True stops the work with ``Cancelled``.
    stack, errors, noise_source
        The ring stack at :func:`profile_radii` (thickness 1) and its standard errors (R, H, W, 3),
        when already computed (the explorer has them); computed here otherwise.
    photons
        Photons of the table's white run (:func:`.table.table_for`), within
        :data:`.table.PHOTON_RANGE` (TableError otherwise).
    floor
        Relative standard deviation added to every ring (:data:`MODEL_FLOOR`).
    estimator
        ``"nodes"``: Gauss-Newton steps from a fine table's nodes (:mod:`.node_fit`); ``"full"``:
        Levenberg-Marquardt on the table's splines (:mod:`.pixel_fit`), what region fits use.

    Returns
    -------
    OpticalMaps
        (H, W, 3) maps in per mm when the manifest gives ``grid.pitch_mm``, else per grid step.
    """
    check_photons(photons)  # as table_for does, but before the rings that one path computes first
    n, g = sample_optics(dataset, n, g)
    radii = profile_radii(dataset)
    report = _Phases(progress, cancelled)
    scale = np.ones(3) if calibration is None else np.asarray(calibration.scale, np.float64)
    from_spread = stack is None and errors is None and len(dataset.manifest.replicates) <= 1
    if from_spread and estimator == "nodes":
        # The rings, their spread and the fits in one pass over the responses, row by row.
        phase("the look-up table")
        table = table_for(n, g, radii, photons=photons, progress=report.part(0.0, 0.1))
        inflation = t_inflation(error_freedom(dataset, radii, "ring spread"))
        _fits_phase("the rings and the fits", one_pass.fits_compiled())
        fitted, complete = one_pass.fit_in_one_pass(dataset, radii, table, scale, floor, inflation,
                                                    progress=report.part(0.1, 1.0), cancelled=report.cancelled)
        return maps_from_fit(fitted, table, dataset.manifest.pitch_mm, complete, radii, "ring spread", scale)
    inflation = np.ones(len(radii))  # errors given are taken as they are
    if from_spread:
        # The rings and their spread in one pass over the responses (one read of them, not two).
        phase("the rings and their spread")
        stack, errors = ring_stack_and_errors(dataset, radii, progress=report.part(0.0, 0.6))
        noise_source = "ring spread"
        inflation = t_inflation(error_freedom(dataset, radii, noise_source))
    elif stack is None:
        phase("the rings")
        stack = ring_stack(dataset, radii, progress=report.part(0.0, 0.3))
    elif not np.array_equal(stack.radii, radii) or stack.thickness != 1.0 or stack.antialias:
        raise OpticsError(f"the stack given holds radii {stack.radii.tolist()}, not the rings 0..{radii[-1]:g} "
                          f"(thickness 1) that optical maps fit")
    report.check()
    if errors is None:
        phase("the rings' errors")
        errors, noise_source = ring_errors(dataset, radii, progress=report.part(0.3, 0.6))
        inflation = t_inflation(error_freedom(dataset, radii, noise_source))
    report.check()
    phase("the look-up table")
    table = table_for(n, g, radii, photons=photons, progress=report.part(0.6, 0.7))
    report.check()
    _fits_phase("the fits", fits_compiled(estimator))
    fitted = fit_profiles(table, stack.images, errors, scale, cancelled=report.cancelled, counts=stack.counts,
                          floor=floor, inflation=inflation, estimator=estimator, progress=report.part(0.7, 1.0))
    report.progress(1.0)
    whole = np.asarray([_ring_members(r) for r in radii])
    complete = (stack.counts == whole[:, None, None]).all(axis=0)
    return maps_from_fit(fitted, table, dataset.manifest.pitch_mm, complete, radii, noise_source or "given", scale)


def _fits_phase(name: str, compiled: bool) -> None:
    """Name the fits' phase, with :data:`FIRST_RUN` said where their kernel is not ``compiled`` yet."""
    phase(name if compiled else name + FIRST_RUN)


def maps_from_fit(fitted: dict, table: ProfileTable, pitch_mm: float | None, complete: np.ndarray, radii: np.ndarray,
                  noise_source: str, scale: np.ndarray) -> OpticalMaps:
    """The maps of :func:`.pixel_fit.fit_profiles`' result in the table's units converted to per mm."""
    g = table.g
    per = 1.0 / pitch_mm if pitch_mm else 1.0
    musp = (1.0 - g) * np.exp(fitted["u"]) * per
    mua = np.exp(fitted["u"] + fitted["v"]) * per
    # Delta method: log mus' = u + log(1 - g), log mua = u + v.
    musp_se = musp * np.sqrt(fitted["cuu"])
    mua_se = mua * np.sqrt(fitted["cuu"] + 2.0 * fitted["cuv"] + fitted["cvv"])
    converged = fitted["status"] == CONVERGED
    with np.errstate(invalid="ignore"):
        mua_determined = converged & (mua_se < DETERMINED_RELATIVE_ERROR * mua)
        musp_determined = converged & (musp_se < DETERMINED_RELATIVE_ERROR * musp)
    as32 = lambda array: array.astype(np.float32)  # noqa: E731
    return OpticalMaps(as32(mua), as32(musp), as32(mua_se), as32(musp_se), mua_determined & musp_determined,
                       mua_determined, musp_determined, as32(fitted["chi2"]), fitted["rings"], complete,
                       "per_mm" if pitch_mm else "per_grid_step", pitch_mm, table.n, g, CHANNELS,
                       np.asarray(radii, np.float64), noise_source, np.asarray(scale, np.float64))


def _ring_members(radius: float) -> int:
    return len(ring_geometry(float(radius)).offsets)


class _Phases:
    """Progress of consecutive phases as one fraction, and the cancel question asked between them."""

    def __init__(self, progress, cancelled):
        self._progress = progress
        self._cancelled = cancelled

    def progress(self, fraction: float) -> None:
        if self._progress is not None:
            self._progress(fraction)
        self.check()

    def part(self, start: float, stop: float):
        return lambda fraction: self.progress(start + (stop - start) * fraction)

    def check(self) -> None:
        if self._cancelled is not None and self._cancelled():
            raise Cancelled("optical maps cancelled")

    def cancelled(self) -> bool:
        return self._cancelled is not None and bool(self._cancelled())
