"""Fit each layer's absorption to a region's ring-light profile, with honest uncertainty.

Channels are independent given the scattering (one white database serves them all), so each
channel is fitted on its own: the parameters are ``theta_k = log mua_k`` per layer, within
:data:`MUA_BOUNDS`, by weighted least squares in log space,

    residual_r = (log E_measured(r) - log E_model(r)) / (sigma_r / E_measured(r)),

over the rings from r = 0 up to the first whose E is below :data:`MIN_SNR` sigma. ``sigma_r``
combines the measured standard error (:mod:`.measured`), the white run's own noise
(:meth:`.forward.Forward.variance`) and a relative floor :data:`RELATIVE_FLOOR` for what neither
shows (noise common to every lit point, database binning); the floor is 0 where the measured error
holds the noise the lit points share (a dataset's replicates, :mod:`.measured`).

Uncertainty. Each ``theta_k`` gets an interval where the fit's chi-square stays within
:data:`JOINT_CHI2` of its minimum: the Fisher (Wald) interval where it is narrow (half-width below
:data:`WALD_LIMIT`), inside the bounds and where the profile chi-square (the others refitted with
``theta_k`` held) at its ends has risen by at least :data:`JOINT_CHI2`; else the profile
likelihood's, its end found by Brent's method, out to a bound where it stays within. (Where two
layers can trade absorption, the chi-square is a curved valley, far from the quadratic the Fisher
matrix assumes, and a Wald interval can leave out values that fit as well.)
:data:`JOINT_CHI2` = 5.85 gives each channel 98.4 %, so a layer's three channels together hold the
truth with 95.4 % (two sigma). A layer whose absorption in some channel can rise to the upper bound
within that region is *not determined*: the data do not bound that channel's colour.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .forward import SMALLEST_E, Forward

# scipy.optimize (least_squares, brentq) is imported by the functions that fit: with scipy.stats it
# took 1.1-1.3 s of CPU to import, over a third of every ringlight command's start (the command
# line imports this module for `ringlight layers`), whether it fits anything or not.

MUA_BOUNDS = (1e-5, 10.0)
"""Absorption per grid step that a fit may take (10: opaque within a tenth of a step)."""
MIN_SNR = 3.0
RELATIVE_FLOOR = 0.01
JOINT_CHI2 = 5.85
"""Chi-square (1 degree of freedom) quantile 0.954 ** (1 / 3): three channels jointly two sigma."""
WALD_LIMIT = 1.0
"""Half-width of a Wald interval in log absorption beyond which the profile likelihood is
followed instead (the quadratic approximation no longer holds)."""
PROFILE_TOLERANCE = 0.005
"""Log absorption to which an interval's end is found (0.5 %: at 0.05 the ends alone added about
0.0025 xy to every region)."""
BRACKET_STEP = 0.5
"""Log absorption of the first step outward that brackets a profile-likelihood end (:func:`_profile_end`;
half the Wald half-width where that is narrower than :data:`WALD_LIMIT`)."""
LOOSE_TOLERANCE = 1e-5
"""Relative tolerance (ftol, xtol, gtol) of the refits along a profile and of a structure search's
quick fits, where the chi-square is only compared with thresholds (:data:`JOINT_CHI2`, BIC
differences) far coarser than the 1e-4 or so of itself this leaves; the reported fits keep
least squares' defaults."""
START_GRID = (0.005, 0.05, 0.5)
"""Absorption per layer of the start grid: from every combination a short fit, the best few are
fitted fully (the fit has local minima, e.g. a deep layer absorbing what an upper one should)."""
COARSE_GRID = (0.01, 0.3)
SHORT_STEPS = 4
LOOSE = {"ftol": LOOSE_TOLERANCE, "xtol": LOOSE_TOLERANCE, "gtol": LOOSE_TOLERANCE}
"""scipy's least_squares tolerances at :data:`LOOSE_TOLERANCE` (also the joint fit's)."""
FITTED_STARTS = 2


@dataclass(frozen=True)
class ChannelFit:
    """One channel's fit.

    Attributes
    ----------
    mua
        (L,) fitted absorption per layer, per grid step.
    interval
        (L, 2) each layer's absorption range within the joint two-sigma region.
    unbounded
        (L,) bool: the range reaches the upper bound (the data do not bound the absorption).
    used
        Rings fitted (from r = 0).
    chi2
        The fit's chi-square over ``used`` rings.
    model, sigma
        (R,) the fitted profile at every ring and the standard deviation each ring was weighted by.
    data_minima
        (L,) log absorptions each: the fits of the first pass, weighted by the data's noise alone
        (:func:`data_sigma`), which a fit of the same data with the model taken as exact finds
        first (:func:`.limit.exact_regions` starts from them).
    valleys
        Per layer ``k``, a dict: at each log absorption of layer ``k`` held along its profile
        likelihood (the searches for its interval's ends), the other layers' refitted log
        absorptions ((L - 1,)). Another fit of the same data starts its own refits from them.
    """

    mua: np.ndarray
    interval: np.ndarray
    unbounded: np.ndarray
    used: int
    chi2: float
    model: np.ndarray
    sigma: np.ndarray
    data_minima: tuple[np.ndarray, ...] = ()
    valleys: tuple[dict[float, np.ndarray], ...] = ()

    @property
    def dof(self) -> int:
        return max(self.used - len(self.mua), 0)


def used_rings(measured: np.ndarray, sigma: np.ndarray) -> int:
    """Rings from r = 0 up to (not including) the first whose value is below MIN_SNR sigma."""
    good = np.isfinite(measured) & (measured > MIN_SNR * sigma)
    return int(np.argmin(good)) if not good.all() else len(good)


def fit_channels(forward: Forward, measured: np.ndarray, error: np.ndarray, intervals: bool = True,
                 floor: float = RELATIVE_FLOOR, guides: list[ChannelFit] | None = None) -> list[ChannelFit]:
    """:func:`fit_channel` for each channel of ``measured`` and ``error`` (R, C) (with its
    ``guides`` fit when given): with ``intervals``, the channels in threads (the forward model's
    kernel releases the GIL); a quick fit's channels one after another."""
    channels = measured.shape[1]
    guides = guides or [None] * channels
    if not intervals:
        # A quick fit's time is least squares' own Python (three quarters of a layers3 search's
        # fits, the model a fifth), which holds the GIL: in threads its channels only contend for it
        # (layers3's search of 1000 photons on 2 cores: 32 CPU-s and 30 s of wall time; one after
        # another 23 CPU-s and 24 s, the same fits bit for bit).
        return [fit_channel(forward, measured[:, c], error[:, c], False, floor, guides[c]) for c in range(channels)]
    with ThreadPoolExecutor(max_workers=max(1, min(channels, os.cpu_count() or 1))) as pool:
        return list(pool.map(lambda c: fit_channel(forward, measured[:, c], error[:, c], intervals, floor, guides[c]),
                             range(channels)))


def data_sigma(error: np.ndarray, measured: np.ndarray, floor: float = RELATIVE_FLOOR) -> np.ndarray:
    """Each ring's standard deviation of E that the fit assumes for the data (arrays of one shape):
    the measured ``error`` and the relative ``floor`` (:data:`RELATIVE_FLOOR`), which stands in for
    the noise the data do not show (0 where the data's noise is measured in full: replicates)."""
    return np.hypot(error, floor * np.abs(measured))


def ring_sigma(error: np.ndarray, white_variance: np.ndarray, measured: np.ndarray,
               floor: float = RELATIVE_FLOOR) -> np.ndarray:
    """Each ring's standard deviation of E: its measured ``error``, the white run's
    ``white_variance`` at the fit and the relative ``floor`` (arrays of one shape)."""
    return np.sqrt(error ** 2 + white_variance + (floor * measured) ** 2)


def fit_channel(forward: Forward, measured: np.ndarray, error: np.ndarray, intervals: bool = True,
                floor: float = RELATIVE_FLOOR, guide: ChannelFit | None = None) -> ChannelFit:
    """Fit one channel: ``measured`` and ``error`` (R,) are the region's E(r) and its standard
    error at ``forward.radii``; ``floor`` the relative floor (:func:`data_sigma`). Without
    ``intervals`` (a structure search's quick fit) the fit starts from equal absorptions only and
    no intervals are computed. ``guide``, a fit of the same data, ``floor`` and ``forward``'s profile
    whose second pass weighed by other white-run noise (:func:`.limit.exact_regions` fits the
    model taken as exact, guided by the main fit), lends its first pass's minima
    (:attr:`ChannelFit.data_minima`: where this fit's first pass ends, as its weights are the
    same), so the start grid is not searched again; and its intervals and valleys
    (:attr:`ChannelFit.valleys`), where this fit's ends are sought first and its refits start."""
    layers = forward.structure.layers
    low, high = math.log(MUA_BOUNDS[0]), math.log(MUA_BOUNDS[1])
    sigma = data_sigma(error, measured, floor)
    used = min(used_rings(measured, sigma), forward.reached)
    if used <= layers:
        mua = np.full(layers, np.nan)
        interval = np.tile(np.array(MUA_BOUNDS), (layers, 1))
        return ChannelFit(mua, interval, np.ones(layers, bool), used, math.nan, np.full(len(measured), np.nan), sigma)
    loose = {} if intervals else LOOSE

    def weighted(deviation):
        """The objective with each ring weighted by ``deviation`` (R,)."""
        return _objective(forward, used, np.log(measured[:used]), deviation[:used] / measured[:used])

    def fitted(residuals, jacobian, starts):
        from scipy.optimize import least_squares

        return [least_squares(residuals, start, jac=jacobian, bounds=(low, high), method="trf", **loose)
                for start in starts]

    residuals, jacobian = weighted(sigma)
    if guide is not None and guide.data_minima:
        starts = list(guide.data_minima)
    elif intervals:
        starts = _starts(residuals, jacobian, layers, low, high)
    else:  # a structure search's quick fit: equal starting absorptions only
        starts = [np.full(layers, math.log(value)) for value in COARSE_GRID]
    results = fitted(residuals, jacobian, starts)
    best = min(results, key=lambda result: result.cost)
    # The second pass weighs by the white run's noise at the first pass's best fit too, and starts
    # again from each first-pass fit that fits about as well under the new weights (within
    # JOINT_CHI2 of the lowest): another minimum may then be lower. A quick fit goes on from its best.
    # A model without noise of its own (:class:`.limit.ExactForward`) leaves the weights as they were.
    white = forward.variance(np.exp(best.x))
    if np.any(white):
        sigma = ring_sigma(error, white, measured, floor)
        residuals, jacobian = weighted(sigma)
        if intervals:
            costs = np.array([np.sum(residuals(result.x) ** 2) for result in results])
            starts = [result.x for result, cost in zip(results, costs) if cost <= costs.min() + JOINT_CHI2]
        else:
            starts = [best.x]
        best = min(fitted(residuals, jacobian, starts), key=lambda result: result.cost)
    theta = best.x
    chi2 = 2.0 * best.cost
    interval = np.full((layers, 2), np.nan)
    unbounded = np.zeros(layers, bool)
    valleys = []
    if intervals:
        covariance = np.linalg.pinv(best.jac.T @ best.jac)
        spread = math.sqrt(JOINT_CHI2) * np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        guided = guide is not None and len(guide.valleys) == layers
        for k in range(layers):
            valley = {}
            for side, bound in enumerate((low, high)):
                profile = _Profile(residuals, jacobian, theta, k, low, high, guide.valleys[k] if guided else None)
                hint = math.log(guide.interval[k, side]) if guided else None
                interval[k, side] = math.exp(_interval_end(profile, spread[k], bound, chi2, hint))
                valley.update(profile.solved)
            valleys.append(valley)
            unbounded[k] = math.log(interval[k, 1]) >= high - 1e-9
    return ChannelFit(np.exp(theta), interval, unbounded, used, chi2, forward.profile(np.exp(theta)), sigma,
                      tuple(result.x for result in results), tuple(valleys))


def _starts(residuals, jacobian, layers: int, low: float, high: float) -> list[np.ndarray]:
    """Where the full fits start: a few steps of least squares from every combination of
    :data:`START_GRID` (:data:`COARSE_GRID` beyond two layers), the :data:`FITTED_STARTS` best."""
    from scipy.optimize import least_squares

    values = START_GRID if layers <= 2 else COARSE_GRID
    short = [least_squares(residuals, np.log(np.array(combination)), jac=jacobian, bounds=(low, high),
                           method="trf", max_nfev=SHORT_STEPS)
             for combination in itertools.product(values, repeat=layers)]
    return [result.x for result in sorted(short, key=lambda result: result.cost)[:FITTED_STARTS]]


def _objective(forward: Forward, used: int, target: np.ndarray, relative: np.ndarray):
    """``(residuals, jacobian)`` of ``theta`` for the first ``used`` rings; both come from one
    evaluation of the model per ``theta`` (least squares asks for them in turn)."""
    memo = {}

    def evaluate(theta):
        key = theta.tobytes()
        if key not in memo:
            memo.clear()
            profile, slopes = forward.profile(np.exp(theta), derivatives=True)
            profile = np.maximum(profile, SMALLEST_E)
            memo[key] = ((target - np.log(profile[:used])) / relative,
                         -(slopes[:used] * np.exp(theta)) / profile[:used, None] / relative[:, None])
        return memo[key]

    return (lambda theta: evaluate(theta)[0]), (lambda theta: evaluate(theta)[1])


def _interval_end(profile: _Profile, spread: float, bound: float, chi2: float, hint: float | None = None) -> float:
    """The end of ``profile``'s layer's interval toward ``bound`` (``low`` or ``high``), from its
    fit ``theta[k]`` of chi-square ``chi2``: the Wald end ``theta[k] -+ spread`` where it is narrow,
    inside the bounds and confirmed by the profile chi-square there; else the profile likelihood's
    end (:func:`_profile_end`, sought first at ``hint`` when given), searched beyond the Wald end
    where only the confirmation failed."""
    theta = profile.theta[profile.k]
    if abs(theta - bound) <= 1e-9:
        return bound
    wald = theta + math.copysign(spread, bound - theta)
    step = max(BRACKET_STEP * min(spread, WALD_LIMIT) / WALD_LIMIT, 10 * PROFILE_TOLERANCE)
    if spread > WALD_LIMIT or (wald - bound) * (theta - bound) <= 0.0:  # wide, or at or past the bound
        return _profile_end(profile, theta, bound, chi2, step, hint)
    if profile.chi2(wald) - chi2 < JOINT_CHI2:
        return _profile_end(profile, wald, bound, chi2, step, hint)
    return wald


def _profile_end(profile: _Profile, start: float, bound: float, chi2: float, step: float = BRACKET_STEP,
                 hint: float | None = None) -> float:
    """Where, from ``start`` (inside the region) toward ``bound``, the profile chi-square exceeds the
    minimum ``chi2`` by :data:`JOINT_CHI2`: ``bound`` if it never does there, else to within
    :data:`PROFILE_TOLERANCE`, taken that far outward (an interval errs wide, never narrow).

    The end is bracketed by steps outward from ``start``, ``step`` and doubling, so that each refit
    starts near the last (from the bound back it took 6-29 model evaluations a refit); Brent's method
    then finds the root of ``sqrt(profile chi2 - chi2) - sqrt(JOINT_CHI2)``, the same end, which is
    close to linear where the chi-square is close to quadratic (the chi-square itself rises 10^8-fold
    towards an opaque layer, and Brent's method crawled along it: 13-17 refits an end). ``hint``,
    the end of another fit of the same data (under other weights), is tried first: beyond the end,
    it closes the bracket; within, the steps go on from it, from :data:`PROFILE_TOLERANCE` ten times
    (the ends of layers3's allowed-width fit lay 0.001-0.36 from the main fit's)."""
    excess = lambda value: profile.chi2(value) - chi2 - JOINT_CHI2
    if excess(bound) < 0.0:
        return bound
    direction = math.copysign(1.0, bound - start)
    inner, outer = start, bound
    if hint is not None and min((hint - start) * direction, (bound - hint) * direction) > PROFILE_TOLERANCE:
        if excess(hint) >= 0.0:
            outer = hint
        else:
            inner, step = hint, 10 * PROFILE_TOLERANCE
    while outer == bound and (bound - inner) * direction > 2.0 * step:
        trial = inner + direction * step
        if excess(trial) >= 0.0:
            outer = trial
            break
        inner, step = trial, 2.0 * step
    from scipy.optimize import brentq

    rise = lambda value: math.sqrt(max(profile.chi2(value) - chi2, 0.0)) - math.sqrt(JOINT_CHI2)
    end = brentq(rise, inner, outer, xtol=PROFILE_TOLERANCE)
    return min(end + PROFILE_TOLERANCE, profile.high) if bound > start else max(end - PROFILE_TOLERANCE, profile.low)


class _Profile:
    """The profile chi-square of ``theta[k]``: the chi-square with ``theta[k]`` held at a value and
    the other layers refitted. Each refit starts where the other layers' fits at the two nearest
    values held so far point (the valley followed, not climbed again from the minimum: 3-10 model
    evaluations a refit where starting at the minimum took 10-20; extrapolating along the valley
    cut layers3's red intervals from 242 evaluations to 198)."""

    def __init__(self, residuals, jacobian, theta: np.ndarray, k: int, low: float, high: float,
                 valley: dict[float, np.ndarray] | None = None):
        self.residuals, self.jacobian, self.theta, self.k = residuals, jacobian, theta, k
        self.low, self.high = low, high
        self.others = [j for j in range(len(theta)) if j != k]
        self.solved = {float(theta[k]): theta[self.others]}
        """The other layers' refits at each value held (and at the fit itself)."""
        self.valley = dict(valley or {})
        """Another fit's :attr:`solved` of the same data (:attr:`ChannelFit.valleys`): refits start
        from it too, this profile's own refits taking the place of its values."""
        self.values: dict[float, float] = {}
        """The profile chi-square at each value held so far (Brent's method asks again for its
        bracket's ends)."""

    def chi2(self, value: float) -> float:
        value = float(value)
        if value not in self.values:
            self.values[value] = self._refitted(value)
        return self.values[value]

    def _start(self, value: float) -> np.ndarray:
        """Where the refit at ``value`` starts: the other layers' fits at the two nearest values held
        (or in :attr:`valley`), extrapolated along the line through them to ``value`` (within the
        bounds), or the nearest's alone while only one is held."""
        points = {**self.valley, **self.solved}
        nearest = sorted(points, key=lambda held: abs(held - value))[:2]
        if len(nearest) < 2:
            return points[nearest[0]]
        near, far = nearest
        slope = (points[near] - points[far]) / (near - far)
        return np.clip(points[near] + slope * (value - near), self.low, self.high)

    def _refitted(self, value: float) -> float:
        if not self.others:
            return float(np.sum(self.residuals(np.array([value])) ** 2))

        def full(free):
            values = self.theta.copy()
            values[self.others] = free
            values[self.k] = value
            return values

        from scipy.optimize import least_squares

        result = least_squares(lambda free: self.residuals(full(free)), self._start(value),
                               jac=lambda free: self.jacobian(full(free))[:, self.others], bounds=(self.low, self.high),
                               method="trf", **LOOSE)
        self.solved[value] = result.x
        return 2.0 * result.cost
