"""Per-pixel fits of a homogeneous half-space to ring profiles: weighted least squares by
Levenberg-Marquardt on the look-up table (:mod:`.table`), compiled and run over every pixel and
channel at once.

For one pixel and channel, with measured E_r, their standard deviations sigma_r and the rig's
scale ``s`` (1 for a simulated dataset, :mod:`ringlight.core.optics.calibration` for a real one), the fit minimises::

    chi2(u, v) = sum_r ((E_r - s exp(logE_r(u, v))) / sigma_r)^2,   u = log mus, v = log (mua / mus)

over the rings with a finite value and sigma (at least :data:`MIN_RINGS`). The standard errors are
those of the linearised fit, ``C = (J^T W J)^-1`` at the minimum (the delta method carries them to
mus' = (1 - g) e^u and mua = e^(u + v)). A fit starts from the previous pixel's result in its row
(neighbours are alike), or, for the first pixel of a row and whenever that start does not converge,
from the best node of a coarse search of the table.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .table import ProfileTable, interpolate

MIN_RINGS = 3
MAX_ITERATIONS = 40
TOLERANCE = 1e-5
"""Largest step in (u, v) at which a fit has converged."""
DECREMENT = 1e-4
"""Newton decrement (chi2 units) at which a fit has converged: the step left is below 1 % of a
standard error."""
COARSE_STRIDE = 6
"""Table nodes between the points of the coarse search (in u and in v)."""
CONVERGED, NO_DATA, NOT_CONVERGED, AT_EDGE = 0, 1, 2, 3
"""Status of a fit: converged inside the table; fewer than MIN_RINGS usable rings; no convergence;
the minimum lies on the table's edge (beyond the scattering or absorption it spans)."""


def fit_profiles(table: ProfileTable, measured: np.ndarray, sigma: np.ndarray, scale: np.ndarray,
                 cancelled=None) -> dict[str, np.ndarray]:
    """Fit every pixel and channel of ``measured`` (R, H, W, C) with ``sigma`` (R, H, W, C) and the
    rig's ``scale`` (C,).

    Returns a dict of (H, W, C) float64 arrays ``u``, ``v``, ``cuu``, ``cuv``, ``cvv`` (the fit and
    its covariance in the table's coordinates), ``chi2``, ``rings`` (used) and int8 ``status``
    (:data:`CONVERGED` ...). ``cancelled()`` is asked between bands of rows; True stops the work by
    raising :class:`ringlight.core.errors.Cancelled`.
    """
    from ..errors import Cancelled

    rings, height, width, channels = measured.shape
    out = {name: np.full((height, width, channels), np.nan) for name in ("u", "v", "cuu", "cuv", "cvv", "chi2")}
    out["rings"] = np.zeros((height, width, channels), np.int32)
    out["status"] = np.full((height, width, channels), NO_DATA, np.int8)
    measured = np.ascontiguousarray(measured, np.float32)
    sigma = np.ascontiguousarray(sigma, np.float32)
    scale = np.asarray(scale, np.float64)
    band = max(1, (1 << 16) // max(1, width * channels))
    for row0 in range(0, height, band):
        if cancelled is not None and cancelled():
            raise Cancelled("cancelled")
        row1 = min(height, row0 + band)
        _fit_rows(table.log_profile, table.u0, table.du, table.v0, table.dv, measured, sigma, scale, row0, row1,
                  out["u"], out["v"], out["cuu"], out["cuv"], out["cvv"], out["chi2"], out["rings"], out["status"])
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def _fit_rows(log_profile, u0, du, v0, dv, measured, sigma, scale, row0, row1, u_out, v_out, cuu, cuv, cvv, chi2_out,
              rings_out, status):
    width = measured.shape[2]
    channels = measured.shape[3]
    rings = measured.shape[0]
    for y in numba.prange(row0, row1):
        # Scratch arrays once per row (an allocation per fit cost a tenth of its time).
        result = np.empty(8)
        used = np.empty(rings, np.bool_)
        values = np.empty(rings)
        slopes = np.empty((rings, 2))
        for c in range(channels):
            start_u = math.nan
            start_v = math.nan
            for x in range(width):
                _fit_one(log_profile, u0, du, v0, dv, measured[:, y, x, c], sigma[:, y, x, c], scale[c],
                         start_u, start_v, result, used, values, slopes)
                code = int(result[7])
                status[y, x, c] = code
                rings_out[y, x, c] = int(result[6])
                if code == NO_DATA:
                    continue
                u_out[y, x, c] = result[0]
                v_out[y, x, c] = result[1]
                cuu[y, x, c] = result[2]
                cuv[y, x, c] = result[3]
                cvv[y, x, c] = result[4]
                chi2_out[y, x, c] = result[5]
                if code == CONVERGED:
                    start_u = result[0]
                    start_v = result[1]


@numba.njit(cache=True)
def _chi2(log_profile, u0, du, v0, dv, measured, sigma, scale, used, u, v, values, slopes):
    """chi2 at (u, v), or inf outside the table; fills ``values`` with the model's E (scale
    included) and ``slopes`` with d log E / d(u, v)."""
    if not interpolate(log_profile, u0, du, v0, dv, u, v, values, slopes):
        return math.inf
    total = 0.0
    for r in range(measured.shape[0]):
        if used[r]:
            values[r] = scale * math.exp(values[r])
            residual = (measured[r] - values[r]) / sigma[r]
            total += residual * residual
    return total


@numba.njit(cache=True)
def _coarse_start(log_profile, u0, du, v0, dv, measured, sigma, scale, used):
    """(u, v) of the coarse search's best node (interior nodes, every COARSE_STRIDE-th)."""
    best = math.inf
    best_u = u0 + du * (log_profile.shape[0] // 2)
    best_v = v0 + dv * (log_profile.shape[1] // 2)
    for k in range(2, log_profile.shape[0] - 3, COARSE_STRIDE):
        for j in range(2, log_profile.shape[1] - 3, COARSE_STRIDE):
            total = 0.0
            for r in range(measured.shape[0]):
                if used[r]:
                    residual = (measured[r] - scale * math.exp(log_profile[k, j, r])) / sigma[r]
                    total += residual * residual
            if total < best:
                best = total
                best_u = u0 + k * du
                best_v = v0 + j * dv
    return best_u, best_v


@numba.njit(cache=True)
def _fit_one(log_profile, u0, du, v0, dv, measured, sigma, scale, start_u, start_v, result, used, values, slopes):
    """Fit one profile into ``result``: (u, v, Cuu, Cuv, Cvv, chi2, rings used, status); ``used``,
    ``values`` and ``slopes`` are scratch of the rings' size."""
    result[:] = math.nan
    rings = measured.shape[0]
    used[:] = False
    count = 0
    for r in range(rings):
        if math.isfinite(measured[r]) and math.isfinite(sigma[r]) and sigma[r] > 0.0:
            used[r] = True
            count += 1
    result[6] = count
    if count < MIN_RINGS:
        result[7] = NO_DATA
        return
    for attempt in range(2):
        if attempt == 0 and math.isfinite(start_u):
            u, v = start_u, start_v
        elif attempt == 0:
            continue
        else:
            u, v = _coarse_start(log_profile, u0, du, v0, dv, measured, sigma, scale, used)
        status, u, v, a_uu, a_uv, a_vv, chi2 = _levenberg_marquardt(log_profile, u0, du, v0, dv, measured, sigma,
                                                                    scale, used, u, v, values, slopes)
        if status == CONVERGED or attempt == 1:
            break
    determinant = a_uu * a_vv - a_uv * a_uv
    result[0] = u
    result[1] = v
    if determinant > 0.0:
        result[2] = a_vv / determinant
        result[3] = -a_uv / determinant
        result[4] = a_uu / determinant
    result[5] = chi2
    result[7] = status


@numba.njit(cache=True, inline="always")
def _normal_equations(measured, sigma, used, values, slopes):
    """``(A_uu, A_uv, A_vv, b_u, b_v)``: ``A = J^T W J`` and ``b = J^T W (measured - model)`` over the
    rings ``used``, with the model ``values`` (R,) and its log-slopes ``slopes`` (R, 2) at the fit."""
    a_uu = a_uv = a_vv = b_u = b_v = 0.0
    for r in range(measured.shape[0]):
        if used[r]:
            model = values[r]
            weight = 1.0 / (sigma[r] * sigma[r])
            j_u = model * slopes[r, 0]
            j_v = model * slopes[r, 1]
            residual = measured[r] - model
            a_uu += weight * j_u * j_u
            a_uv += weight * j_u * j_v
            a_vv += weight * j_v * j_v
            b_u += weight * j_u * residual
            b_v += weight * j_v * residual
    return a_uu, a_uv, a_vv, b_u, b_v


@numba.njit(cache=True)
def _levenberg_marquardt(log_profile, u0, du, v0, dv, measured, sigma, scale, used, u, v, values, slopes):
    """Minimise chi2 from (u, v). Returns (status, u, v, A_uu, A_uv, A_vv, chi2), A = J^T W J."""
    low_u = u0 + 1.0 * du
    high_u = u0 + (log_profile.shape[0] - 2.0) * du - 1e-9
    low_v = v0 + 1.0 * dv
    high_v = v0 + (log_profile.shape[1] - 2.0) * dv - 1e-9
    u = min(max(u, low_u), high_u)
    v = min(max(v, low_v), high_v)
    damping = 1e-3
    chi2 = _chi2(log_profile, u0, du, v0, dv, measured, sigma, scale, used, u, v, values, slopes)
    a_uu = a_uv = a_vv = 0.0
    status = NOT_CONVERGED
    for _ in range(MAX_ITERATIONS):
        a_uu, a_uv, a_vv, b_u, b_v = _normal_equations(measured, sigma, used, values, slopes)
        # Converged when the Gauss-Newton step itself is below the tolerance: no trial (near the
        # minimum a trial's chi2 differs from the current one by rounding only, and was refused
        # a dozen times, most of a fit's time).
        determinant = a_uu * a_vv - a_uv * a_uv
        if determinant > 0.0:
            newton_u = (a_vv * b_u - a_uv * b_v) / determinant
            newton_v = (a_uu * b_v - a_uv * b_u) / determinant
            # The Newton decrement (the chi2 the step would gain) below DECREMENT: the remaining
            # error is below a hundredth of a standard error, whatever the parameter's scale.
            if (abs(newton_u) < TOLERANCE and abs(newton_v) < TOLERANCE) or newton_u * b_u + newton_v * b_v < DECREMENT:
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
            trial = _chi2(log_profile, u0, du, v0, dv, measured, sigma, scale, used, new_u, new_v, values, slopes)
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
            _chi2(log_profile, u0, du, v0, dv, measured, sigma, scale, used, u, v, values, slopes)
            status = CONVERGED
            break
        if abs(step_u) < TOLERANCE and abs(step_v) < TOLERANCE:
            status = CONVERGED
            break
    if status == CONVERGED:
        # The curvature at the minimum (values and slopes are at (u, v) now).
        a_uu, a_uv, a_vv, _, _ = _normal_equations(measured, sigma, used, values, slopes)
        edge = 1e-6
        if u <= low_u + edge or u >= high_u - edge or v <= low_v + edge or v >= high_v - edge:
            status = AT_EDGE
    return status, u, v, a_uu, a_uv, a_vv, chi2
