"""The maps' node fits (:mod:`.node_fit`) a chunk of a grid row at a time, with its pixels as the
lanes of loops the compiler vectorises.

A chunk is :data:`CHUNK` pixels of one row, its rings held channel by channel, (C, R, CHUNK). Each
channel's fits start where the last fit of the row's previous chunk ended (neighbours are alike),
so one node serves the whole chunk's first step: the rings' weights
(:func:`.pixel_data.chunk_profiles`), that step's sums and its normal equations are loops over the
chunk's pixels, 8 of them to an instruction. Each pixel then takes its step at theta from its own
node (:func:`.node_fit.step_at_theta`), or, where its first step landed beyond a node of the
chunk's, goes on with node steps from there (:func:`.node_fit.node_steps`): each pixel's fit is the
one :func:`.node_fit.node_steps` makes from the chunk's start, which ``tests/test_optics_chunk_fit.py``
checks lane by lane. A pixel whose rings borrow an error other than ring 0's from ring 1 is fitted
alone from that start (its weights by :func:`.pixel_data.pixel_profile`), and where node steps do
not settle, a pixel's fit is the full fit. Where the row's previous chunk gives no start, pixels are
fitted alone, each from the last one's minimum, until one converges; where the start's node is at
the fine table's edge, every pixel of the chunk is. A cache-resident chunk's fits
took 44 ns a pixel channel this way, 84 pixel by pixel (``benchmarks/bench_chunk.py``, one thread).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .node_fit import NODE_STEPS, node_steps, normal_step, step_at_theta
from .pixel_data import chunk_profiles, pixel_profile, write_fit
from .pixel_fit import CONVERGED, MIN_RINGS, NO_DATA, fit_one_profile

CHUNK = 64
"""Pixels of a row fitted together: their profiles and weights (8 rings, 3 channels: 37 KB) stay
in the core's cache."""
SETTLED, LANDED, BEYOND = 1.0, 2.0, 0.0
"""A lane's first step from the chunk's node: landed within a node of it (its step at theta
follows), landed beyond (its node steps go on from there), or its fit is its own from the start
(singular normal equations, irregular rings or too few; or no first step taken)."""


@numba.njit(cache=True, inline="always")
def chunk_scratch(channels, rings):
    """A row's work arrays for :func:`node_fit_chunk`: the rings' ``data`` and ``weight`` lane by
    lane (C, R, CHUNK) and pixel by pixel (C, CHUNK, R), the rings ``used`` and ``irregular`` (C,
    CHUNK), the first step's sums (5, CHUNK), its landing (u, v, settled) (3, CHUNK) and nodes (2,
    CHUNK), one fit's result (6,), and one pixel's scratch for :func:`.pixel_data.pixel_profile`
    and the full fit: ``result`` (10,), ``variance``, ``data``, ``weight``, ``values`` (R,),
    ``slopes`` (2, R), and the pixel's E, errors (R, 1, 1, C) and members (R, 1, 1)."""
    return (np.empty((channels, rings, CHUNK)), np.empty((channels, rings, CHUNK)),
            np.empty((channels, CHUNK, rings)), np.empty((channels, CHUNK, rings)),
            np.empty((channels, CHUNK), np.int64), np.empty((channels, CHUNK), np.int64), np.empty((5, CHUNK)),
            np.empty((3, CHUNK)), np.empty((2, CHUNK), np.int64), np.empty(6),
            (np.empty(10), np.empty(rings), np.empty(rings), np.empty(rings), np.empty(rings), np.empty((2, rings)),
             np.empty((rings, 1, 1, channels), np.float32), np.empty((rings, 1, 1, channels), np.float32),
             np.empty((rings, 1, 1), np.int64)))


@numba.njit(parallel=True, cache=True, nogil=True)
def node_fit_rows(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, measured, sigma,
                  scale, errors_given, counts, floor, inflation, row0, row1, u_out, v_out, cuu, cuv, cvv, chi2_out,
                  rings_out, status, steps):
    """The node fits of grid rows ``row0 .. row1`` of ``measured`` and ``sigma`` (R, H, W, C) into
    the (H, W, C) outputs (as :func:`.pixel_fit.fit_profiles` fills them), and ``steps`` (H, W, C)
    int8: the node steps each fit took (0: the full fit's)."""
    for y in numba.prange(row0, row1):
        _node_fit_row(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, measured, sigma,
                      scale, errors_given, counts, floor, inflation, y, u_out, v_out, cuu, cuv, cvv, chi2_out,
                      rings_out, status, steps)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _node_fit_row(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, measured, sigma,
                  scale, errors_given, counts, floor, inflation, y, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out,
                  status, steps):
    """Row ``y``'s fits, each chunk's rings copied channel by channel first. A function of its own
    outside the parallel loop (numba's trap: inlined into it, fits gave wrong covariances, 0.61)."""
    rings, width, channels = measured.shape[0], measured.shape[2], measured.shape[3]
    lanes = np.zeros((channels, rings, CHUNK), np.float32)
    lane_errors = np.zeros((channels, rings, CHUNK), np.float32)
    scratch = chunk_scratch(channels, rings)
    starts = np.full((channels, 2), np.nan)
    for x0 in range(0, width, CHUNK):
        pixels = min(CHUNK, width - x0)
        for c in range(channels):
            for r in range(rings):
                for x in range(pixels):
                    lanes[c, r, x] = measured[r, y, x0 + x, c]
                    lane_errors[c, r, x] = sigma[r, y, x0 + x, c]
        members = counts[:, y:y + 1, x0:x0 + pixels] if errors_given else counts[:, :1, :1]
        node_fit_chunk(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, lanes,
                       lane_errors, pixels, scale, errors_given, members, floor, inflation, y, x0, starts, u_out, v_out,
                       cuu, cuv, cvv, chi2_out, rings_out, status, steps, scratch)


# Reassociation lets the compiler vectorise each pixel's sums over the rings in its step at theta,
# as in the pixel's own fit (:func:`.node_fit.node_steps`).
@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract", "arcp", "nsz"})
def node_fit_chunk(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, lanes, lane_errors,
                   pixels, scale, errors_given, counts, floor, inflation, y, x0, starts, u_out, v_out, cuu, cuv, cvv,
                   chi2_out, rings_out, status, steps, scratch):
    """The fits of the first ``pixels`` columns of ``lanes`` and ``lane_errors`` (C, R, CHUNK)
    float32, C-contiguous: E and its standard errors (or deviations, as ``errors_given`` says) of
    row ``y``'s pixels from column ``x0``, channel by channel; ``counts`` (R, 1, pixels) their
    rings' members. ``starts`` (C, 2) holds each channel's start (u, v), NaN for none, and on return
    the next chunk's. Every output of every pixel and channel is written (NaN values where there is
    no data). ``scratch``: :func:`chunk_scratch`."""
    lane_data, lane_weight, data, weight, used, irregular, sums, landing, landed, fitted, profile = scratch
    chunk_profiles(lanes, lane_errors, errors_given, counts, inflation, floor, pixels, lane_data, lane_weight, used,
                   irregular)
    # Each pixel's rings side by side for its own steps, whose sums over them the compiler
    # vectorises (bench_chunk.py: 67 -> 51 ns a fit; read across the lanes, 8 loads each).
    for c in range(lanes.shape[0]):
        for x in range(pixels):
            for r in range(lanes.shape[1]):
                data[c, x, r] = lane_data[c, r, x]
                weight[c, x, r] = lane_weight[c, r, x]
    for c in range(lanes.shape[0]):
        start_u = starts[c, 0]
        start_v = starts[c, 1]
        chunk_u = chunk_v = math.nan  # the chunk's start, once there is one
        stepped = False  # whether the lanes took their first step from it
        for x in range(pixels):
            if not math.isfinite(chunk_u) and math.isfinite(start_u):
                chunk_u, chunk_v = start_u, start_v
                stepped = _first_steps(nodes, node_u0, node_du, node_v0, node_dv, lane_data, lane_weight, used,
                                       irregular, c, scale[c], chunk_u, chunk_v, sums, landing, landed)
            onward = landing[2, x] if stepped else BEYOND
            if onward == SETTLED and step_at_theta(nodes, node_u0, node_du, node_v0, node_dv, landed[0, x],
                                                   landed[1, x], landing[0, x], landing[1, x], data, weight, c, x,
                                                   scale[c], fitted):
                _write(fitted, 1, used[c, x], y, x0 + x, c, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status,
                       steps)
                start_u, start_v = fitted[0], fitted[1]
                continue
            # Where the chunk took no first step (no start yet, or its node at the table's edge), from
            # the last fit's minimum, pixel after pixel.
            begin_u, begin_v, taken = start_u, start_v, 0
            if onward == LANDED:
                # A lane that landed beyond the chunk's node goes on from there, as its own fit would.
                taken = node_steps(nodes, node_u0, node_du, node_v0, node_dv, data, weight, c, x, scale[c],
                                   landing[0, x], landing[1, x], 1, fitted)
                if taken > 0:
                    _write(fitted, taken, used[c, x], y, x0 + x, c, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out,
                           status, steps)
                    start_u, start_v = fitted[0], fitted[1]
                    continue
                taken = NODE_STEPS  # they did not settle: the full fit's
            if stepped:
                begin_u, begin_v = chunk_u, chunk_v
            start_u, start_v = _fit_alone(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0,
                                          dv, lanes, lane_errors, errors_given, counts, floor, inflation, data, weight,
                                          used, irregular, c, x, scale[c], begin_u, begin_v, taken, y, x0 + x, u_out,
                                          v_out, cuu, cuv, cvv, chi2_out, rings_out, status, steps, fitted, profile)
        starts[c, 0] = start_u
        starts[c, 1] = start_v


# Contraction lets the compiler fuse the lanes' products and sums; each lane's sums over the rings
# keep their order (the loops over the rings are outside the lanes').
@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract", "arcp", "nsz"})
def _first_steps(nodes, node_u0, node_du, node_v0, node_dv, data, weight, used, irregular, c, scale, u, v, sums,
                 landing, landed):
    """Channel ``c``'s first Gauss-Newton step of every lane of ``data`` and ``weight`` (C, R,
    CHUNK) from the node nearest (``u``, ``v``): ``landing`` (3, CHUNK) the (u, v) it reaches and
    where it landed (:data:`SETTLED`, :data:`LANDED` or :data:`BEYOND`), ``landed`` (2, CHUNK) the
    node nearest that point. ``sums`` (5, CHUNK) is scratch. False, and nothing filled, where the
    node is within two of the fine grid's ends."""
    k = int(round((u - node_u0) / node_du))
    j = int(round((v - node_v0) / node_dv))
    if k < 2 or j < 2 or k > nodes.shape[0] - 3 or j > nodes.shape[1] - 3:
        return False
    width = data.shape[2]
    for x in range(width):
        for m in range(5):
            sums[m, x] = 0.0
    for r in range(data.shape[1]):
        model = scale * nodes[k, j, 0, r]
        j_u = scale * nodes[k, j, 1, r]
        j_v = scale * nodes[k, j, 2, r]
        for x in range(width):
            w = weight[c, r, x]
            residual = data[c, r, x] - model
            sums[0, x] += w * j_u * j_u
            sums[1, x] += w * j_u * j_v
            sums[2, x] += w * j_v * j_v
            sums[3, x] += w * j_u * residual
            sums[4, x] += w * j_v * residual
    node_u = node_u0 + k * node_du
    node_v = node_v0 + j * node_dv
    for x in range(width):
        determinant, step_u, step_v = normal_step(sums[0, x], sums[1, x], sums[2, x], sums[3, x], sums[4, x])
        landing_u = node_u + step_u
        landing_v = node_v + step_v
        next_k = int(round((landing_u - node_u0) / node_du))
        next_j = int(round((landing_v - node_v0) / node_dv))
        onward = determinant > 0.0 and irregular[c, x] == 0 and used[c, x] >= MIN_RINGS
        near = abs(next_k - k) <= 1 and abs(next_j - j) <= 1
        landing[0, x] = landing_u
        landing[1, x] = landing_v
        landing[2, x] = (SETTLED if near else LANDED) if onward else BEYOND
        landed[0, x] = next_k
        landed[1, x] = next_j
    return True


# The node fit's flags stated: a callee without its own takes its first caller's (the pixel's weights
# and steps as node_fit.node_steps takes them).
@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract", "arcp", "nsz"})
def _fit_alone(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, lanes, lane_errors,
               errors_given, counts, floor, inflation, data, weight, used, irregular, c, x, scale, start_u, start_v,
               first, y, column, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status, steps, fitted, profile):
    """Lane ``x``, channel ``c`` of ``data`` and ``weight`` (C, CHUNK, R) fitted on its own from
    (``start_u``, ``start_v``), node step ``first`` on: its rings' weights by
    :func:`.pixel_data.pixel_profile` where they are irregular, node steps, else the full fit.
    Returns the next fit's start: this fit's minimum, or NaN where it did not converge."""
    result, variance, one_data, one_weight, values, slopes, pixel, pixel_errors, members = profile
    rings = lanes.shape[1]
    if irregular[c, x] != 0:
        # The pixel's rings as pixel_profile reads a grid's, (R, 1, 1, C) and (R, 1, 1): a copy, where
        # views of the lanes made its compilation 3 s longer (reshape's error messages).
        for r in range(rings):
            pixel[r, 0, 0, c] = lanes[c, r, x]
            pixel_errors[r, 0, 0, c] = lane_errors[c, r, x]
            members[r, 0, 0] = counts[r, 0, x] if errors_given else 0
        used[c, x] = pixel_profile(pixel, pixel_errors, errors_given, members, inflation, floor, 0, 0, c, variance,
                                   one_data, one_weight)
        for r in range(rings):
            data[c, x, r] = one_data[r]
            weight[c, x, r] = one_weight[r]
    rings_out[y, column, c] = used[c, x]
    if used[c, x] < MIN_RINGS:
        for m in range(6):
            fitted[m] = math.nan
        _write(fitted, 0, used[c, x], y, column, c, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status, steps)
        status[y, column, c] = NO_DATA
        return math.nan, math.nan
    if math.isfinite(start_u):
        taken = node_steps(nodes, node_u0, node_du, node_v0, node_dv, data, weight, c, x, scale, start_u, start_v,
                           first, fitted)
        if taken > 0:
            _write(fitted, taken, used[c, x], y, column, c, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status,
                   steps)
            return fitted[0], fitted[1]
    for r in range(rings):
        one_data[r] = data[c, x, r]
        one_weight[r] = weight[c, x, r]
    fit_one_profile(log_profile, coarse, u0, du, v0, dv, one_data, one_weight, scale, result, values, slopes)
    status[y, column, c] = int(result[7])
    steps[y, column, c] = 0
    write_fit(result, y, column, c, u_out, v_out, cuu, cuv, cvv, chi2_out)
    return (result[0], result[1]) if int(result[7]) == CONVERGED else (math.nan, math.nan)


@numba.njit(cache=True, inline="always")
def _write(fitted, taken, count, y, x, c, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status, steps):
    """A node fit's ``fitted`` (u, v, Cuu, Cuv, Cvv, chi2) into the maps' (H, W, C) outputs at pixel
    (y, x), channel c: converged after ``taken`` node steps, ``count`` rings used."""
    write_fit(fitted, y, x, c, u_out, v_out, cuu, cuv, cvv, chi2_out)
    rings_out[y, x, c] = count
    status[y, x, c] = CONVERGED
    steps[y, x, c] = taken
