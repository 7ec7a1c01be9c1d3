"""Each ring's standard deviation in a profile fit, from the standard errors of its ring light image.

A ring's standard deviation is its standard error; a ring without one (NaN: fewer than 2
members, e.g. r = 0) takes the relative error of the nearest ring that has one (the lower ring
first between two as near) times sqrt(that ring's members / its own) (independent members of
equal relative noise); a relative ``floor`` is added in quadrature for what the noise does not show
(:data:`.maps.MODEL_FLOOR`). The maps' fits compute its square pixel by pixel (:func:`profile_variance`),
never holding an (R, H, W, C) array of it.
"""

from __future__ import annotations

import math

import numba
import numpy as np


def ring_sigma(images: np.ndarray, errors: np.ndarray, counts: np.ndarray, floor: float) -> np.ndarray:
    """(R, H, W, C) float32 standard deviation of each ring's E (module docstring): ``images`` and
    their standard ``errors`` (R, H, W, C), ``counts`` (R, H, W) the rings' members; NaN where the
    image is NaN or no ring of the pixel has a standard error.

    Examples
    --------
    >>> images = np.array([4.0, 2.0, 1.0]).reshape(3, 1, 1, 1)
    >>> errors = np.array([np.nan, 0.2, 0.2]).reshape(3, 1, 1, 1)
    >>> counts = np.array([1, 4, 8]).reshape(3, 1, 1)
    >>> ring_sigma(images, errors, counts, 0.0).ravel().astype(float).round(3).tolist()  # r = 0: 10 % x sqrt(4)
    [0.8, 0.2, 0.2]
    """
    rings, height, width, channels = images.shape
    out = np.empty((rings, height, width, channels), np.float32)
    _ring_sigma_kernel(np.ascontiguousarray(images, np.float32), np.ascontiguousarray(errors, np.float32),
                       np.ascontiguousarray(counts, np.int32), np.ones(rings), float(floor), out)
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _ring_sigma_kernel(images, errors, counts, inflation, floor, out):
    rings, height, width, channels = images.shape
    for y in numba.prange(height):
        variance = np.empty(rings)
        for x in range(width):
            for c in range(channels):
                profile_variance(images[:, y, x, c], errors[:, y, x, c], counts[:, y, x], inflation, floor, variance)
                for r in range(rings):
                    out[r, y, x, c] = math.sqrt(variance[r])


@numba.njit(cache=True, inline="always", error_model="numpy")
def profile_variance(images, errors, counts, inflation, floor, variance):
    """Fill ``variance`` (R,) float64 with the squared standard deviations of one pixel's rings
    (module docstring): ``images``, ``errors`` (R,) of one channel, each error times ``inflation``
    (R,) (:func:`.maps.t_inflation`), ``counts`` (R,) the rings' members. A ring of E = 0 has no
    relative error (it borrows one, as a NaN error does). Variances, not deviations: the fit
    weighs a ring by 1 / variance, and a square root per ring was a tenth of a fit's time."""
    rings = images.shape[0]
    for r in range(rings):
        deviation = np.float64(errors[r]) * inflation[r]
        variance[r] = deviation * deviation
    for r in range(rings):
        if (math.isfinite(variance[r]) and images[r] != 0.0) or not math.isfinite(images[r]):
            continue
        # The nearest ring with a relative error, the lower first at equal distance.
        value = math.nan
        for distance in range(1, rings):
            for other in (r - distance, r + distance):
                if 0 <= other < rings and math.isfinite(errors[other] * inflation[other] / images[other]):
                    relative = abs(errors[other] * inflation[other] / images[other])
                    value = abs(images[r]) * relative * math.sqrt(counts[other] / max(counts[r], 1))
                    break
            if math.isfinite(value):
                break
        variance[r] = value * value
    for r in range(rings):
        scaled = floor * images[r]
        variance[r] += scaled * scaled
