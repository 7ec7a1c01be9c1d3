"""Fit the three channels of a region's profile together, with the noise they share.

The per-channel fits (:mod:`.fit`) treat R, G and B as independent. Neither of the two noises that
set the fit's weights is: the white run serves every channel from the same photons, and noise
common to every lit point (a projector's flicker, a simulator's shared walks) moves every channel
alike. A deviation common to the channels then pulls each channel's absorption its own way and
turns the colour, which a fit that knows the deviation is common does not do.

The joint fit is generalised least squares on log E over all channels' parameters
``theta[c, k] = log mua[c, k]``: at each ring the residuals of the channels fitted there (the rings
each channel's own fit used) are whitened by the Cholesky factor of their covariance, in log space,

    S_r = diag(error_c^2) / E_c^2 + cov_white(r)[c, c'] / (E_c E_c') + f^2 (rho + (1 - rho) delta_cc'),

the measured standard errors (independent between channels), the white run's covariance between
channels from its photons (:meth:`.forward.Forward.covariance`), and the relative
floor ``f`` (:data:`.fit.RELATIVE_FLOOR`) with correlation ``rho`` between channels, which is
fitted too: each of :data:`FLOOR_CORRELATIONS` is tried and the fit of the highest likelihood
(lowest ``chi2 + sum log det S_r``) kept. Each starts from the per-channel fits, and like them
weighs by the white run's noise at the start, then again at the result; its chi-square and Fisher
matrix are those under the weights at its result. Its Fisher matrix gives each layer's
chromaticity a two-sigma ellipse (the delta method), which :mod:`.layer_colour` joins with the
per-channel profile-likelihood region where the chi-square is close to quadratic.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .fit import LOOSE, MUA_BOUNDS, RELATIVE_FLOOR, ChannelFit, ring_sigma
from .forward import SMALLEST_E, Forward

# scipy.optimize is imported where the joint fit runs, as in .fit (its import cost every command).

FLOOR_CORRELATIONS = (0.0, 0.5, 0.9)
"""Correlations between channels of the relative floor that the fit chooses from, by likelihood.
The simulator's samples have it high (layers3, five seeds: the seed-to-seed differences of the
region mean correlate 0.90-0.99 between channels); a capture whose unexplained noise is the
channels' own has it near 0, and a fit that assumed 0.9 there averaged chi2/dof 2.0 (up to 4.3:
past the misfit threshold) where the channels' own fits had 0.4."""
MAX_EVALUATIONS = 200
"""A fit's profile evaluations at most. An absorption that the data hardly bound (a channel that
hardly absorbs) has a chi-square almost flat towards the lower bound, and the optimiser crawls
along it: 900 evaluations (9 s) on layers3's top red, for a chi-square 0.5 lower. The fit then
stops where it is, which fits as well as the bound would."""
ELLIPSE_CHI2 = -2.0 * math.log1p(-0.954)
"""Chi-square (2 degrees of freedom) of a two-sigma (95.4 %) region in xy: 6.16. With 2 degrees of
freedom the chi-square is exponential of mean 2, so its quantile p is -2 ln(1 - p) (the same double
as ``scipy.stats.chi2.ppf(0.954, 2)``)."""
ELLIPSE_POINTS = 32


@dataclass(frozen=True)
class JointFit:
    """The channels' joint fit.

    Attributes
    ----------
    mua
        (C, L) absorption per channel and layer, per grid step.
    covariance
        (C L, C L) Fisher covariance of ``log mua`` (flattened channel-major), from the Gauss-Newton
        matrix at the fit (pseudo-inverse).
    chi2
        Generalised chi-square over the rings used, under the weights ``S_r`` at ``mua``.
    deviance
        ``chi2 + sum log det S_r``: minus twice the log-likelihood (up to a constant), which
        compares fits under different covariances (floor correlations, structures).
    floor_correlation
        The one of :data:`FLOOR_CORRELATIONS` whose fit has the lowest deviance.
    points
        Residuals fitted (every channel's rings).
    model, sigma
        (R, C) the fitted profile and each ring's standard deviation at every ring, fitted or not
        (the diagonal of ``S_r`` times E where fitted).
    """

    mua: np.ndarray
    covariance: np.ndarray
    chi2: float
    deviance: float
    floor_correlation: float
    points: int
    model: np.ndarray
    sigma: np.ndarray

    @property
    def at_bound(self) -> np.ndarray:
        """(C, L) bool: the absorption lies at a bound of :data:`.fit.MUA_BOUNDS`."""
        theta = np.log(self.mua)
        return np.any([np.abs(theta - math.log(bound)) < 1e-6 for bound in MUA_BOUNDS], axis=0)

    @property
    def dof(self) -> int:
        return max(self.points - self.mua.size, 0)

    def layer_covariance(self, layer: int) -> np.ndarray:
        """(C, C) covariance of ``log mua[:, layer]``."""
        channels, layers = self.mua.shape
        index = np.arange(channels) * layers + layer
        return self.covariance[np.ix_(index, index)]


def fit_jointly(forward: Forward, measured: np.ndarray, error: np.ndarray, fits: list[ChannelFit],
                floor: float = RELATIVE_FLOOR, data_covariance: np.ndarray | None = None) -> JointFit | None:
    """Refit the channels of ``fits`` (per-channel fits of ``measured`` and ``error`` (R, C) with
    ``forward``, relative ``floor``) together; ``data_covariance`` (R, C, C), when the data's
    covariance between channels is measured (replicates), replaces ``diag(error^2)``. None when a
    channel's own fit
    failed (too few rings), or the joint fit does not fit better than the channels' fits under its
    own weights (it starts from them, so it cannot, unless the optimiser fails)."""
    if any(not np.all(np.isfinite(f.mua)) for f in fits):
        return None
    channels = len(fits)
    layers = len(fits[0].mua)
    used = np.array([f.used for f in fits])
    low, high = math.log(MUA_BOUNDS[0]), math.log(MUA_BOUNDS[1])
    start = np.log(np.clip(np.array([f.mua for f in fits]), *MUA_BOUNDS)).ravel()
    target = np.log(np.where(measured > 0, measured, np.nan))
    pool = ThreadPoolExecutor(max_workers=max(1, min(channels, os.cpu_count() or 1)))
    white_covariances = {}

    def white_covariance(mua, rings):
        """``forward.covariance(mua, rings)``, once per absorption and ring count: the fits under
        each floor correlation start at the same absorptions, and the chosen fit's result is asked
        for again at the end (every ring: the same call when every ring is fitted). That is 2-3 of
        a joint fit's 10 covariances, which took 86 % of its CPU (test_joint_fit's white run)."""
        key = (mua.tobytes(), rings)
        if key not in white_covariances:
            white_covariances[key] = forward.covariance(mua, rings)
        return white_covariances[key]

    try:
        def profiles(theta):
            """Per channel ``(profile (R,), slopes (R, L))`` at ``theta`` (C L,)."""
            mua = np.exp(theta.reshape(channels, layers))
            return list(pool.map(lambda c: forward.profile(mua[c], derivatives=True), range(channels)))

        def weighted(theta, correlation):
            """``(residuals, jacobian, log_det)`` under the weights at ``theta``; ``log_det`` sums
            ``log det S_r`` over the rings and channels fitted."""
            covariance = _ring_covariances(white_covariance, np.exp(theta.reshape(channels, layers)), measured,
                                           error, used, correlation, floor, data_covariance)
            whiten, log_det = _whitening(covariance, used)
            return *_objective(profiles, whiten, target, used, channels, layers), log_det

        def fitted(correlation):
            """``(deviance, chi2, theta, Fisher matrix)`` with the floor correlated ``correlation``
            between channels; None when the optimiser fails or ends worse than it started."""
            from scipy.optimize import least_squares

            theta = start
            for _ in range(2):  # weights at the channels' fits, then at the joint fit's first result
                residuals, jacobian, _ = weighted(theta, correlation)
                start_cost = 0.5 * float(np.sum(residuals(theta) ** 2))
                best = least_squares(residuals, theta, jac=jacobian, bounds=(low, high), method="trf",
                                     max_nfev=MAX_EVALUATIONS, **LOOSE)
                if best.status < 0 or best.cost > start_cost:
                    return None
                theta = best.x
            residuals, jacobian, log_det = weighted(theta, correlation)  # at the result
            chi2 = float(np.sum(residuals(theta) ** 2))
            return chi2 + log_det, chi2, theta, jacobian(theta).T @ jacobian(theta)

        # Without a floor its correlation changes nothing: one fit.
        results = {correlation: fitted(correlation) for correlation in (FLOOR_CORRELATIONS if floor > 0 else (0.0,))}
        results = {correlation: result for correlation, result in results.items() if result is not None}
        if not results:
            return None
        correlation = min(results, key=lambda value: results[value][0])
        deviance, chi2, theta, fisher = results[correlation]
        mua = np.exp(theta.reshape(channels, layers))
        model = np.stack([forward.profile(mua[c]) for c in range(channels)], axis=1)
    finally:
        pool.shutdown()
    sigma = ring_sigma(error, np.diagonal(white_covariance(mua, len(forward.radii)), axis1=1, axis2=2), measured,
                       floor)
    return JointFit(mua, np.linalg.pinv(fisher), chi2, deviance, correlation, int(used.sum()), model, sigma)


def _ring_covariances(white_covariance, mua: np.ndarray, measured: np.ndarray, error: np.ndarray,
                      used: np.ndarray, correlation: float, floor: float = RELATIVE_FLOOR,
                      data_covariance: np.ndarray | None = None) -> np.ndarray:
    """(R, C, C) ``S_r`` (module docstring) at absorption ``mua`` (C, L) and ``floor`` correlated
    ``correlation`` between channels (``data_covariance`` (R, C, C) for the measured errors'
    ``diag(error^2)`` when given), for the channels that use each ring (the other entries are finite
    and unused); rings no channel uses are left at the identity. ``white_covariance(mua, rings)``
    is the forward model's (:meth:`.forward.Forward.covariance`)."""
    rings, channels = measured.shape
    covariance = np.tile(np.eye(channels), (rings, 1, 1))
    last = int(used.max())
    white = white_covariance(mua, last)
    fitted = np.arange(last)[:, None] < used[None, :]
    scale = np.where(fitted, np.abs(measured[:last]), 1.0)  # a ring a channel does not use may hold 0
    relative_white = white / (scale[:, :, None] * scale[:, None, :])
    floor_covariance = floor ** 2 * (correlation + (1.0 - correlation) * np.eye(channels))
    if data_covariance is not None:
        data = data_covariance[:last] / (scale[:, :, None] * scale[:, None, :])
    else:
        data = np.zeros((last, channels, channels))
        data[:, np.arange(channels), np.arange(channels)] = (error[:last] / scale) ** 2
    covariance[:last] = np.nan_to_num(data + relative_white + floor_covariance)
    return covariance


def _whitening(covariance: np.ndarray, used: np.ndarray) -> tuple[list[np.ndarray], float]:
    """Per ring, the inverse Cholesky factor of ``S_r`` over the channels that use that ring (empty
    for a ring none uses); and ``sum log det`` of those blocks."""
    whiten, log_det = [], 0.0
    for row, matrix in enumerate(covariance):
        active = np.flatnonzero(row < used)
        if not len(active):
            whiten.append(np.zeros((0, 0)))
            continue
        factor = np.linalg.cholesky(matrix[np.ix_(active, active)])
        whiten.append(np.linalg.inv(factor))
        log_det += 2.0 * float(np.sum(np.log(np.diagonal(factor))))
    return whiten, log_det


def _objective(profiles, whiten: list[np.ndarray], target: np.ndarray, used: np.ndarray, channels: int,
               layers: int):
    """``(residuals, jacobian)`` of ``theta`` (C L,): each ring's whitened log residuals over the
    channels that use it; both from one evaluation of the model per ``theta``."""
    memo = {}
    rows = [(row, np.flatnonzero(row < used)) for row in range(len(whiten)) if len(whiten[row])]

    def evaluate(theta):
        key = theta.tobytes()
        if key not in memo:
            memo.clear()
            mua = np.exp(theta.reshape(channels, layers))
            evaluated = profiles(theta)
            residual_blocks, jacobian_blocks = [], []
            for row, active in rows:
                raw = np.array([target[row, c] - math.log(max(evaluated[c][0][row], SMALLEST_E)) for c in active])
                slope = np.zeros((len(active), channels * layers))
                for i, c in enumerate(active):
                    profile, slopes = evaluated[c]
                    slope[i, c * layers:(c + 1) * layers] = -slopes[row] * mua[c] / max(profile[row], SMALLEST_E)
                residual_blocks.append(whiten[row] @ raw)
                jacobian_blocks.append(whiten[row] @ slope)
            memo[key] = np.concatenate(residual_blocks), np.vstack(jacobian_blocks)
        return memo[key]

    return (lambda theta: evaluate(theta)[0]), (lambda theta: evaluate(theta)[1])


def chromaticity_ellipse(centre: np.ndarray, gradient: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(ELLIPSE_POINTS, 2) the two-sigma ellipse in xy of a colour at ``centre`` (2,) whose
    chromaticity changes by ``gradient`` (2, C) per unit of ``log mua`` (C,) with ``covariance``
    (C, C): the delta method, ``G S G^T``, at :data:`ELLIPSE_CHI2`. Empty when that is not finite."""
    spread = gradient @ covariance @ gradient.T
    if not np.all(np.isfinite(spread)):
        return np.zeros((0, 2))
    values, vectors = np.linalg.eigh(0.5 * (spread + spread.T))
    angles = np.linspace(0.0, 2.0 * math.pi, ELLIPSE_POINTS, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles)])
    return centre + (vectors @ (np.sqrt(np.clip(values, 0.0, None) * ELLIPSE_CHI2)[:, None] * circle)).T
