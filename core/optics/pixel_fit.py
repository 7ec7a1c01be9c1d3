"""Per-pixel fits of a homogeneous half-space to ring profiles: weighted least squares by
Levenberg-Marquardt on the look-up table (:mod:`.table`), compiled and run over every pixel and
channel at once.

For one pixel and channel, with measured E_r, their standard deviations sigma_r and the rig's
scale ``s`` (1 for a simulated dataset, :mod:`ringlight.core.optics.calibration` for a real one), the fit minimises::

    chi2(u, v) = sum_r ((E_r - s exp(logE_r(u, v))) / sigma_r)^2,   u = log mus, v = log (mua / mus)

over the rings with a finite value and sigma (at least :data:`MIN_RINGS`). The standard errors are
those of the linearised fit, ``C = (J^T W J)^-1`` at the minimum (the delta method carries them to
mus' = (1 - g) e^u and mua = e^(u + v)). A fit starts where the previous pixel's fit in its row
ended (neighbours are alike; the model there is known, so the start costs no look-up), or, for the
first pixel of a row and whenever that start does not converge, from the best node of a coarse
search of the table. Near the minimum the last Gauss-Newton step is taken without a look-up
after it (:data:`FINAL_DECREMENT`): a fit costs about one look-up of the table
(``benchmarks/bench_optics.py``: 2.6 before, on a homogeneous map at 3 % noise per response).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..kernel_cache import is_cached
from .pixel_data import pixel_profile, row_scratch, write_fit
from .table import ProfileTable, interpolate

MIN_RINGS = 3
MAX_ITERATIONS = 40
TOLERANCE = 1e-5
"""Largest step in (u, v) at which a fit has converged."""
DECREMENT = 1e-4
"""Newton decrement (chi2 units) at which a fit has converged: the step left is below 1 % of a
standard error."""
FINAL_DECREMENT = 1e-2
"""Newton decrement (chi2 units) below which the Gauss-Newton step is taken as the fit's last step,
unchecked (no look-up after it), when it is also below :data:`FINAL_STEP`: the start lies within a
tenth of a standard error of the minimum, where the model is linear to far better than the fit's
precision, so the step lands on the minimum within :data:`DECREMENT`'s precision (the fits equal
scipy's least squares to 3 % of a standard error, ``tests/test_optics_pixel_fit.py``). Its chi2 is
the quadratic model's (chi2 less the decrement), its covariance the curvature at the start."""
FINAL_STEP = 1e-2
"""Largest unchecked last step in u and in v (log units): the curvature at the start is the
minimum's within about 1 % (a step of 0.04 in v, a tenth of a poorly determined v's standard error,
gave v's variance 3 % high)."""
COARSE_STRIDE = 6
"""Table nodes between the points of the coarse search (in u and in v)."""
CONVERGED, NO_DATA, NOT_CONVERGED, AT_EDGE = 0, 1, 2, 3
"""Status of a fit: converged inside the table; fewer than MIN_RINGS usable rings; no convergence;
the minimum lies on the table's edge (beyond the scattering or absorption it spans)."""


def fit_profiles(table: ProfileTable, measured: np.ndarray, sigma: np.ndarray, scale: np.ndarray,
                 cancelled=None, counts: np.ndarray | None = None, floor: float = 0.0,
                 inflation: np.ndarray | None = None, estimator: str = "full", progress=None) -> dict[str, np.ndarray]:
    """Fit every pixel and channel of ``measured`` (R, H, W, C) with ``sigma`` (R, H, W, C) and the
    rig's ``scale`` (C,).

    With the rings' members ``counts`` (R, H, W), ``sigma`` holds the standard errors of
    ``measured`` instead, which each fit turns into its rings' variances
    (:func:`.pixel_data.pixel_profile`, with ``floor`` and each ring's error times ``inflation``
    (R,), default 1): the maps' way, without an (R, H, W, C) array of them (it took as long as
    the stack, ``benchmarks/bench_optics.py``).

    Returns a dict of (H, W, C) float64 arrays ``u``, ``v``, ``cuu``, ``cuv``, ``cvv`` (the fit and
    its covariance in the table's coordinates), ``chi2``, ``rings`` (used), int8 ``status``
    (:data:`CONVERGED` ...) and int8 ``node_steps`` (the nodes a node fit stepped from; 0 for a
    full fit). ``cancelled()`` is asked between bands of rows; True stops the work by
    raising :class:`ringlight.core.errors.Cancelled`. ``progress(fraction)`` is called after each
    band (the fraction of the rows fitted).

    ``estimator`` ``"full"`` fits each profile by Levenberg-Marquardt on the table's splines (this
    module); ``"nodes"`` by Gauss-Newton steps from a finer table's nodes (:mod:`.node_fit`, the
    maps' estimator), the full fit where those steps do not settle.
    """
    from ..errors import Cancelled
    from .chunk_fit import node_fit_rows
    from .node_fit import fine_nodes

    if estimator not in ("full", "nodes"):
        raise ValueError(f"estimator must be 'full' or 'nodes', not {estimator!r}")

    rings, height, width, channels = measured.shape
    out = fit_outputs(height, width, channels)
    measured = np.ascontiguousarray(measured, np.float32)
    sigma = np.ascontiguousarray(sigma, np.float32)
    scale = np.asarray(scale, np.float64)
    errors_given = counts is not None
    counts = np.ascontiguousarray(counts, np.int32) if errors_given else np.zeros((rings, 1, 1), np.int32)
    inflation = np.ones(rings) if inflation is None else np.asarray(inflation, np.float64)
    coarse = coarse_nodes(table.log_profile)
    band = max(1, (1 << 16) // max(1, width * channels))
    for row0 in range(0, height, band):
        if cancelled is not None and cancelled():
            raise Cancelled("cancelled")
        row1 = min(height, row0 + band)
        if estimator == "nodes":
            node_fit_rows(*fine_nodes(table), table.log_profile, coarse, table.u0, table.du, table.v0, table.dv,
                          measured, sigma, scale, errors_given, counts, float(floor), inflation, row0, row1, out["u"],
                          out["v"], out["cuu"], out["cuv"], out["cvv"], out["chi2"], out["rings"], out["status"],
                          out["node_steps"])
        else:
            _fit_rows(table.log_profile, coarse, table.u0, table.du, table.v0, table.dv, measured, sigma, scale,
                      errors_given, counts, float(floor), inflation, row0, row1, out["u"], out["v"], out["cuu"],
                      out["cuv"], out["cvv"], out["chi2"], out["rings"], out["status"])
        if progress is not None:
            progress(row1 / height)
    return out


def fits_compiled(estimator: str = "nodes") -> bool:
    """Whether numba's cache holds the kernel :func:`fit_profiles` runs for ``estimator`` (false
    on a first run after an install or an update, when it compiles: about half a minute on two cores)."""
    if estimator == "nodes":
        from .chunk_fit import node_fit_rows

        return is_cached(node_fit_rows)
    return is_cached(_fit_rows)


def fit_outputs(height: int, width: int, channels: int, filled: bool = True) -> dict[str, np.ndarray]:
    """The (H, W, C) outputs of :func:`fit_profiles` before any fit: NaN values, no rings used,
    status :data:`NO_DATA`; with ``filled`` False, not initialised (for a kernel that writes every
    output of every pixel, :func:`.chunk_fit.node_fit_chunk`: the fills cost the maps' pass about 10 ms
    at 800 x 800, a thread's serial work)."""
    def make(dtype, value):
        shape = (height, width, channels)
        return np.full(shape, value, dtype) if filled else np.empty(shape, dtype)
    out = {name: make(np.float64, np.nan) for name in ("u", "v", "cuu", "cuv", "cvv", "chi2")}
    out["rings"] = make(np.int32, 0)
    out["status"] = make(np.int8, NO_DATA)
    out["node_steps"] = make(np.int8, 0)
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def _fit_rows(log_profile, coarse, u0, du, v0, dv, measured, sigma, scale, errors_given, counts, floor, inflation,
              row0, row1, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status):
    for y in numba.prange(row0, row1):
        _fit_row(log_profile, coarse, u0, du, v0, dv, measured, sigma, scale, errors_given, counts, floor, inflation, y,
                 u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fit_row(log_profile, coarse, u0, du, v0, dv, measured, sigma, scale, errors_given, counts, floor, inflation, y,
             u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status):
    """The fits of grid row ``y``, every channel, pixel after pixel (each starting where the last
    ended). A function of its own, outside the parallel loop, so that the fit's functions are
    inlined into it (a call passing arrays costs their reference counts: 0.2 us a fit; inlined
    into the parallel loop itself they gave wrong covariances, numba 0.61)."""
    width = measured.shape[2]
    channels = measured.shape[3]
    rings = measured.shape[0]
    result, variance, data, weight, values, slopes = row_scratch(rings)
    for c in range(channels):
        start_u = math.nan
        start_v = math.nan
        for x in range(width):
            count = pixel_profile(measured, sigma, errors_given, counts, inflation, floor, y, x, c, variance, data,
                                  weight)
            # ``values`` and ``slopes`` hold the model at (start_u, start_v): the previous fit's last look-up.
            _fit_one(log_profile, coarse, u0, du, v0, dv, data, weight, count, scale[c], start_u, start_v, result,
                     values, slopes)
            code = int(result[7])
            status[y, x, c] = code
            rings_out[y, x, c] = int(result[6])
            if code == NO_DATA:
                continue
            write_fit(result, y, x, c, u_out, v_out, cuu, cuv, cvv, chi2_out)
            if code == CONVERGED:
                start_u = result[8]
                start_v = result[9]
            else:
                start_u = math.nan
                start_v = math.nan


@numba.njit(cache=True, inline="always")
def _chi2(log_profile, u0, du, v0, dv, data, weight, scale, u, v, values, slopes):
    """chi2 at (u, v), or inf outside the table; fills ``values`` with the model's E (scale
    included) and ``slopes`` with d log E / d(u, v), every ring's (the next fit may use others)."""
    if not interpolate(log_profile, u0, du, v0, dv, u, v, values, slopes):
        return math.inf
    for r in range(data.shape[0]):
        values[r] = scale * math.exp(values[r])
    return _residual_chi2(data, weight, values)


@numba.njit(cache=True, inline="always")
def _residual_chi2(data, weight, values):
    """chi2 of the model ``values``: ``data`` and ``weight`` (1 / sigma^2) are 0 at rings not used."""
    total = 0.0
    for r in range(data.shape[0]):
        residual = data[r] - values[r]
        total += weight[r] * residual * residual
    return total


def coarse_nodes(log_profile: np.ndarray) -> np.ndarray:
    """(K', J', R) E at the coarse search's nodes: every :data:`COARSE_STRIDE`-th interior node
    of the table's (K, J, R) ``log_profile`` from node 2 in u and v, made once per map (the
    search took their exponentials at each row's start: 18 us a search, three a row of 2400 fits)."""
    return np.exp(log_profile[2:log_profile.shape[0] - 3:COARSE_STRIDE, 2:log_profile.shape[1] - 3:COARSE_STRIDE])


@numba.njit(cache=True)
def _coarse_start(coarse, u0, du, v0, dv, data, weight, scale):
    """(u, v) of the best node of the coarse search (:func:`coarse_nodes`' E ``coarse``)."""
    best = math.inf
    best_u = u0 + du * (2 + COARSE_STRIDE * (coarse.shape[0] // 2))
    best_v = v0 + dv * (2 + COARSE_STRIDE * (coarse.shape[1] // 2))
    for k in range(coarse.shape[0]):
        for j in range(coarse.shape[1]):
            total = 0.0
            for r in range(data.shape[0]):
                if weight[r] > 0.0:
                    residual = data[r] - scale * coarse[k, j, r]
                    total += weight[r] * residual * residual
            if total < best:
                best = total
                best_u = u0 + (2 + COARSE_STRIDE * k) * du
                best_v = v0 + (2 + COARSE_STRIDE * j) * dv
    return best_u, best_v


@numba.njit(cache=True, inline="always")
def _store_fit(fit, result):
    """A minimiser's return (:func:`_levenberg_marquardt`) into ``result`` (u, v, Cuu, Cuv, Cvv,
    chi2, -, status, last look-up's u, v): the covariance C = A^-1 where A is positive definite."""
    status, u, v, a_uu, a_uv, a_vv, chi2, last_u, last_v = fit
    determinant = a_uu * a_vv - a_uv * a_uv
    result[0] = u
    result[1] = v
    if determinant > 0.0:
        result[2] = a_vv / determinant
        result[3] = -a_uv / determinant
        result[4] = a_uu / determinant
    result[5] = chi2
    result[7] = status
    result[8] = last_u
    result[9] = last_v


@numba.njit(cache=True, inline="always")
def _fit_one(log_profile, coarse, u0, du, v0, dv, data, weight, count, scale, start_u, start_v, result, values,
             slopes):
    """Fit one profile's ``data`` and ``weight`` (R,) (:func:`.pixel_data.pixel_profile`, ``count``
    rings used) into ``result``: (u, v, Cuu, Cuv, Cvv, chi2, rings used, status, and the last
    look-up's u, v); ``values`` and ``slopes`` are scratch of the rings' size, holding the model at
    (``start_u``, ``start_v``) when that is finite, and the model at the last look-up's (u, v) on
    return."""
    result[:] = math.nan
    result[6] = count
    if count < MIN_RINGS:
        result[7] = NO_DATA
        return
    if math.isfinite(start_u):
        fit = _levenberg_marquardt(log_profile, u0, du, v0, dv, data, weight, scale, start_u, start_v, True, values,
                                   slopes)
        if fit[0] != CONVERGED:
            fit = _fit_from_coarse(log_profile, coarse, u0, du, v0, dv, data, weight, scale, values, slopes)
    else:
        fit = _fit_from_coarse(log_profile, coarse, u0, du, v0, dv, data, weight, scale, values, slopes)
    _store_fit(fit, result)


# fastmath False stated: numba would give it the flags of whichever caller compiles it first
# (the node fit's reassociation), and the full fit is the reference.
@numba.njit(cache=True, fastmath=False)
def fit_one_profile(log_profile, coarse, u0, du, v0, dv, data, weight, scale, result, values, slopes):
    """The full fit of one profile's ``data`` and ``weight`` (:func:`.pixel_data.pixel_profile`) from the
    coarse search into ``result`` (as :func:`_fit_one` fills it, but the rings used): the
    estimator of :mod:`.node_fit` calls it where its steps do not settle."""
    result[:] = math.nan
    _store_fit(_fit_from_coarse(log_profile, coarse, u0, du, v0, dv, data, weight, scale, values, slopes), result)


@numba.njit(cache=True)
def _fit_from_coarse(log_profile, coarse, u0, du, v0, dv, data, weight, scale, values, slopes):
    """:func:`_levenberg_marquardt` from the coarse search's best node (a row's first fit, or one
    whose start did not converge): a call of its own, so that the usual fit's code holds one
    inlined minimiser (with two, or a loop around one, a fit took half as long again)."""
    u, v = _coarse_start(coarse, u0, du, v0, dv, data, weight, scale)
    return _levenberg_marquardt(log_profile, u0, du, v0, dv, data, weight, scale, u, v, False, values, slopes)


@numba.njit(cache=True, inline="always")
def _normal_equations(data, weight, values, slopes):
    """``(A_uu, A_uv, A_vv, b_u, b_v)``: ``A = J^T W J`` and ``b = J^T W (data - model)`` with the
    rings' ``weight`` W (0 at rings not used), the model ``values`` (R,) and its log-slopes
    ``slopes`` (2, R) at the fit."""
    a_uu = a_uv = a_vv = b_u = b_v = 0.0
    for r in range(data.shape[0]):
        model = values[r]
        j_u = model * slopes[0, r]
        j_v = model * slopes[1, r]
        residual = data[r] - model
        a_uu += weight[r] * j_u * j_u
        a_uv += weight[r] * j_u * j_v
        a_vv += weight[r] * j_v * j_v
        b_u += weight[r] * j_u * residual
        b_v += weight[r] * j_v * residual
    return a_uu, a_uv, a_vv, b_u, b_v


@numba.njit(cache=True, inline="always")
def _levenberg_marquardt(log_profile, u0, du, v0, dv, data, weight, scale, u, v, known, values, slopes):
    """Minimise chi2 from (u, v) (``known``: ``values`` and ``slopes`` hold the model there, inside
    the table's bounds). Returns (status, u, v, A_uu, A_uv, A_vv, chi2, and the (u, v) of the last
    look-up, whose model ``values`` and ``slopes`` hold), A = J^T W J."""
    low_u = u0 + 1.0 * du
    high_u = u0 + (log_profile.shape[0] - 2.0) * du - 1e-9
    low_v = v0 + 1.0 * dv
    high_v = v0 + (log_profile.shape[1] - 2.0) * dv - 1e-9
    if known:
        chi2 = _residual_chi2(data, weight, values)
    else:
        u = min(max(u, low_u), high_u)
        v = min(max(v, low_v), high_v)
        chi2 = _chi2(log_profile, u0, du, v0, dv, data, weight, scale, u, v, values, slopes)
    last_u, last_v = u, v
    damping = 1e-3
    a_uu = a_uv = a_vv = 0.0
    status = NOT_CONVERGED
    # Whether the curvature A is older than the last look-up (else it is at the minimum, or at the
    # start of the final step).
    stale = False
    for _ in range(MAX_ITERATIONS):
        a_uu, a_uv, a_vv, b_u, b_v = _normal_equations(data, weight, values, slopes)
        # Converged when the Gauss-Newton step itself is below the tolerance: no trial (near the
        # minimum a trial's chi2 differs from the current one by rounding only, and was refused
        # a dozen times, most of a fit's time).
        determinant = a_uu * a_vv - a_uv * a_uv
        if determinant > 0.0:
            newton_u = (a_vv * b_u - a_uv * b_v) / determinant
            newton_v = (a_uu * b_v - a_uv * b_u) / determinant
            # The Newton decrement (the chi2 the step would gain) below DECREMENT: the remaining
            # error is below a hundredth of a standard error, whatever the parameter's scale.
            decrement = newton_u * b_u + newton_v * b_v
            if (abs(newton_u) < TOLERANCE and abs(newton_v) < TOLERANCE) or decrement < DECREMENT:
                status = CONVERGED
                break
            final_u = u + newton_u
            final_v = v + newton_v
            if (decrement < FINAL_DECREMENT and abs(newton_u) < FINAL_STEP and abs(newton_v) < FINAL_STEP
                    and low_u <= final_u <= high_u and low_v <= final_v <= high_v):
                u, v = final_u, final_v
                chi2 = max(chi2 - decrement, 0.0)
                status = CONVERGED
                break
        improved = False
        step_u = step_v = 0.0
        for _ in range(12):
            m_uu = a_uu * (1.0 + damping) + 1e-300
            m_vv = a_vv * (1.0 + damping) + 1e-300
            determinant = m_uu * m_vv - a_uv * a_uv
            if determinant <= 0.0:
                damping *= 10.0
                continue
            step_u = (m_vv * b_u - a_uv * b_v) / determinant
            step_v = (m_uu * b_v - a_uv * b_u) / determinant
            new_u = min(max(u + step_u, low_u), high_u)
            new_v = min(max(v + step_v, low_v), high_v)
            trial = _chi2(log_profile, u0, du, v0, dv, data, weight, scale, new_u, new_v, values, slopes)
            last_u, last_v = new_u, new_v
            if trial <= chi2:
                step_u = new_u - u
                step_v = new_v - v
                u, v, chi2 = new_u, new_v, trial
                damping = max(damping / 4.0, 1e-7)
                improved = True
                break
            damping *= 8.0
        if not improved:
            # No step lowers chi2: the minimum (to the table's precision) is here.
            _chi2(log_profile, u0, du, v0, dv, data, weight, scale, u, v, values, slopes)
            last_u, last_v = u, v
            status = CONVERGED
            stale = True
            break
        if abs(step_u) < TOLERANCE and abs(step_v) < TOLERANCE:
            status = CONVERGED
            stale = True
            break
    if status == CONVERGED:
        if stale:
            # The curvature at the minimum: values and slopes are at (u, v) now.
            a_uu, a_uv, a_vv, _, _ = _normal_equations(data, weight, values, slopes)
        edge = 1e-6
        if u <= low_u + edge or u >= high_u - edge or v <= low_v + edge or v >= high_v - edge:
            status = AT_EDGE
    return status, u, v, a_uu, a_uv, a_vv, chi2, last_u, last_v
