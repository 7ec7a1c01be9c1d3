"""One pixel's data for its fit and its result in the maps, shared by the full fit
(:mod:`.pixel_fit`) and the node fit (:mod:`.node_fit`): the rings' variances, the data and
weights a fit sums over, a row's scratch arrays, and the fit's outputs.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def row_scratch(rings):
    """A row's scratch arrays for its fits: ``result`` (10,), ``variance``, ``data``, ``weight``,
    ``values`` (R,) and ``slopes`` (2, R) (once per row: an allocation per fit cost a tenth of its time)."""
    return (np.empty(10), np.empty(rings), np.empty(rings), np.empty(rings), np.empty(rings),
            np.empty((2, rings)))


@numba.njit(cache=True, inline="always")
def write_fit(result, y, x, c, u_out, v_out, cuu, cuv, cvv, chi2_out):
    """A fit's ``result`` (:func:`.pixel_fit._fit_one`'s layout) into the maps' (H, W, C) outputs at
    pixel (y, x), channel c."""
    u_out[y, x, c] = result[0]
    v_out[y, x, c] = result[1]
    cuu[y, x, c] = result[2]
    cuv[y, x, c] = result[3]
    cvv[y, x, c] = result[4]
    chi2_out[y, x, c] = result[5]


@numba.njit(cache=True, inline="always", error_model="numpy")
def pixel_profile(measured, sigma, errors_given, counts, inflation, floor, y, x, c, variance, data, weight):
    """Fill ``variance``, ``data`` and ``weight`` (1 / variance) (R,) of pixel (y, x), channel c,
    from ``measured`` E and its standard deviations (R, H, W, C); returns the rings used.

    Where ``errors_given``, ``sigma`` holds the standard errors of E, and a ring's variance is
    :mod:`.ring_sigma`'s: its error times ``inflation`` (R,) (:func:`.maps.t_inflation`), squared;
    a ring without one (not finite) or of E = 0 borrows the relative error of the nearest ring with
    one (the lower first at equal distance) times sqrt(that ring's members / its own) (``counts``
    (R, H, W)); then the relative ``floor`` is added in quadrature. Else ``sigma`` is the standard
    deviation itself (NaN where not positive). A ring not used (not finite, or no positive variance)
    weighs 0 and its value is 0, not NaN, so that the fit's sums need no test.

    One loop over the rings, the rule written out in it: a node fit on a cache-resident chunk of 64
    pixels took 141 ns with the rule in four loops over the rings, 124 ns in one, and 270 ns with
    the rule a function called per ring in that loop (numba 0.68, one thread)."""
    rings = data.shape[0]
    count = 0
    for r in range(rings):
        image = measured[r, y, x, c]
        if errors_given:
            deviation = np.float64(sigma[r, y, x, c]) * inflation[r]
            value = deviation * deviation
            if (not math.isfinite(value) or image == 0.0) and math.isfinite(image):
                # The nearest ring with a relative error, the lower first, in one loop: over the pair
                # (r - distance, r + distance) in a loop of its own, a node fit took 120 ns, not 109
                # (r = 0 borrows in every fit; cache-resident chunk, one thread).
                other = -1
                relative = math.nan
                for turn in range(2, 2 * rings):  # r - 1, r + 1, r - 2, r + 2, ...
                    other = r - turn // 2 if turn % 2 == 0 else r + turn // 2
                    if 0 <= other < rings:
                        relative = sigma[other, y, x, c] * inflation[other] / measured[other, y, x, c]
                        if math.isfinite(relative):
                            break
                    other = -1
                deviation = math.nan
                if other >= 0:
                    deviation = abs(image) * abs(relative) * math.sqrt(counts[other, y, x] / max(counts[r, y, x], 1))
                value = deviation * deviation
            scaled = floor * image
            value += scaled * scaled
        else:
            deviation = np.float64(sigma[r, y, x, c])
            value = deviation * deviation if deviation > 0.0 else math.nan
        variance[r] = value
        if math.isfinite(image) and math.isfinite(value) and value > 0.0:
            data[r] = image
            weight[r] = 1.0 / value
            count += 1
        else:
            data[r] = 0.0
            weight[r] = 0.0
    return count


# fastmath False stated (here and in its two helpers): a callee without it takes its first caller's
# flags (docs/guide/development.md), and with the node fit's, the compiler fused each variance's
# sum of squares into a multiply-add, an ulp off pixel_profile's weights in 12 % of them.
@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False)
def chunk_profiles(lanes, lane_errors, errors_given, counts, inflation, floor, pixels, data, weight, used, irregular):
    """:func:`pixel_profile`'s ``data`` and ``weight`` of a chunk's pixels, channel by channel, in
    loops over the pixels that the compiler vectorises (5-6 ns a fit, where a pixel's own rule,
    ring by ring, took 28: ``benchmarks/bench_chunk.py``, one thread).

    ``lanes`` and ``lane_errors`` (C, R, N) float32 hold E and its standard errors (or deviations,
    as ``errors_given`` says) channel by channel, the first ``pixels`` of the N columns in use;
    ``counts`` (R, 1, pixels) the rings' members. Fills ``data`` and ``weight`` (C, R, N) float64,
    ``used`` (C, N) the rings used and ``irregular`` (C, N): nonzero where a ring other than 0
    borrows its error (or ring 0 finds none in ring 1), which only :func:`pixel_profile`'s search
    does. Where ``irregular`` is 0 the values are :func:`pixel_profile`'s, to the bit; columns from
    ``pixels`` on are filled with whatever their lanes hold."""
    channels, rings, width = lanes.shape
    borrowed = np.zeros(width)  # ring 0's error from ring 1's: sqrt(ring 1's members / ring 0's)
    if errors_given and rings > 1:
        for x in range(pixels):
            borrowed[x] = math.sqrt(counts[1, 0, x] / max(counts[0, 0, x], 1))
    for c in range(channels):
        if not errors_given:
            _given_deviations(lanes, lane_errors, c, data, weight, used, irregular)
        elif rings > 1:
            _given_errors(lanes, lane_errors, inflation, floor, borrowed, c, data, weight, used, irregular)
        else:  # one ring with an error: none can lend ring 0 one, pixel_profile's search says so
            for x in range(width):
                used[c, x] = 0
                irregular[c, x] = 1


# Each case a function of its own, its loops without a test of their case inside: with the tests
# inside, the compiler did not vectorise them (23 ns a fit, not 5.5; bench_chunk.py's chunk).
@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False)
def _given_errors(lanes, lane_errors, inflation, floor, borrowed, c, data, weight, used, irregular):
    """:func:`chunk_profiles` of channel c where ``lane_errors`` are standard errors, R > 1."""
    rings, width = lanes.shape[1], lanes.shape[2]
    for x in range(width):
        image = np.float64(lanes[c, 0, x])
        deviation = np.float64(lane_errors[c, 0, x]) * inflation[0]
        value = deviation * deviation
        borrow = (not math.isfinite(value) or image == 0.0) and math.isfinite(image)
        relative = lane_errors[c, 1, x] * inflation[1] / lanes[c, 1, x]
        other = abs(image) * abs(relative) * borrowed[x]
        value = other * other if borrow else value
        irregular[c, x] = 1 if borrow and not math.isfinite(relative) else 0
        scaled = floor * image
        used[c, x] = _store_ring(image, value + scaled * scaled, c, 0, x, data, weight)
    for r in range(1, rings):
        factor = inflation[r]
        for x in range(width):
            image = np.float64(lanes[c, r, x])
            deviation = np.float64(lane_errors[c, r, x]) * factor
            value = deviation * deviation
            irregular[c, x] += 1 if (not math.isfinite(value) or image == 0.0) and math.isfinite(image) else 0
            scaled = floor * image
            used[c, x] += _store_ring(image, value + scaled * scaled, c, r, x, data, weight)


@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False)
def _given_deviations(lanes, lane_errors, c, data, weight, used, irregular):
    """:func:`chunk_profiles` of channel c where ``lane_errors`` are standard deviations."""
    for x in range(lanes.shape[2]):
        used[c, x] = 0
        irregular[c, x] = 0
    for r in range(lanes.shape[1]):
        for x in range(lanes.shape[2]):
            deviation = np.float64(lane_errors[c, r, x])
            value = deviation * deviation if deviation > 0.0 else math.nan
            used[c, x] += _store_ring(np.float64(lanes[c, r, x]), value, c, r, x, data, weight)


@numba.njit(cache=True, inline="always")
def _store_ring(image, value, c, r, x, data, weight):
    """Ring r of lane x, channel c, of E ``image`` and ``value`` its variance: its data and weight
    (0 and 0 where either is not finite, or the variance not positive); 1 where it is used, else 0."""
    good = math.isfinite(image) and math.isfinite(value) and value > 0.0
    data[c, r, x] = image if good else 0.0
    weight[c, r, x] = 1.0 / value if good else 0.0
    return 1 if good else 0
