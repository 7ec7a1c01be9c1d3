"""One pixel's data for its fit and its result in the maps, shared by the full fit
(:mod:`.pixel_fit`) and the node fit (:mod:`.node_fit`): the rings' variances, the data and
weights a fit sums over, a row's scratch arrays, and the fit's outputs.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .ring_sigma import profile_variance


@numba.njit(cache=True, inline="always")
def row_scratch(rings):
    """A row's scratch arrays for its fits: ``result`` (10,), ``variance``, ``data``, ``weight``,
    ``values`` (R,) and ``slopes`` (2, R) (once per row: an allocation per fit cost a tenth of its time)."""
    return np.empty(10), np.empty(rings), np.empty(rings), np.empty(rings), np.empty(rings), np.empty((2, rings))


@numba.njit(cache=True, inline="always")
def pixel_variance(measured, sigma, errors_given, counts, inflation, floor, y, x, c, variance):
    """Fill ``variance`` (R,) with the rings' variances of pixel (y, x), channel c: made from the
    standard errors ``sigma`` where ``errors_given`` (:func:`.ring_sigma.profile_variance`), else
    ``sigma`` squared (NaN where not positive)."""
    if errors_given:
        profile_variance(measured[:, y, x, c], sigma[:, y, x, c], counts[:, y, x], inflation, floor, variance)
    else:
        for r in range(variance.shape[0]):
            deviation = np.float64(sigma[r, y, x, c])
            variance[r] = deviation * deviation if deviation > 0.0 else math.nan


@numba.njit(cache=True, inline="always")
def write_fit(result, y, x, c, u_out, v_out, cuu, cuv, cvv, chi2_out):
    """A fit's ``result`` (:func:`.pixel_fit._fit_one`'s layout) into the maps' (H, W, C) outputs at pixel (y, x), channel c."""
    u_out[y, x, c] = result[0]
    v_out[y, x, c] = result[1]
    cuu[y, x, c] = result[2]
    cuv[y, x, c] = result[3]
    cvv[y, x, c] = result[4]
    chi2_out[y, x, c] = result[5]


@numba.njit(cache=True, inline="always")
def prepare_profile(measured, variance, data, weight):
    """Fill ``data`` and ``weight`` (1 / variance) (R,) of one profile's ``measured`` E and
    ``variance``; a ring not used (not finite, or no positive variance) weighs 0 and its value is
    0, not NaN, so that the fit's sums need no test. Returns the rings used."""
    count = 0
    for r in range(measured.shape[0]):
        if math.isfinite(measured[r]) and math.isfinite(variance[r]) and variance[r] > 0.0:
            data[r] = measured[r]
            weight[r] = 1.0 / variance[r]
            count += 1
        else:
            data[r] = 0.0
            weight[r] = 0.0
    return count
