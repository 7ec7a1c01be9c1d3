"""Each ring's standard deviation in a profile fit, from the standard errors of its ring light image.

A ring's standard deviation is its standard error; a ring without one (NaN: fewer than 2
members, e.g. r = 0) takes the relative error of the nearest ring that has one (the lower ring
first between two as near) times sqrt(that ring's members / its own) (independent members of
equal relative noise); a relative ``floor`` is added in quadrature for what the noise does not show
(:data:`.maps.MODEL_FLOOR`). The rule is :func:`.pixel_data.pixel_profile`'s: the maps' fits
compute its square pixel by pixel, never holding an (R, H, W, C) array of it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .pixel_data import pixel_profile


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
        variance, data, weight = np.empty(rings), np.empty(rings), np.empty(rings)
        for x in range(width):
            for c in range(channels):
                pixel_profile(images, errors, True, counts, inflation, floor, y, x, c, variance, data, weight)
                for r in range(rings):
                    out[r, y, x, c] = math.sqrt(variance[r])
