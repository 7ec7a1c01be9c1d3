"""Per-pixel fits by Gauss-Newton steps from the nodes of a fine table: the maps' estimator,
with no spline look-up and no exponential per fit.

The look-up table (:mod:`.table`) is evaluated once, by its own splines, on a grid
:data:`REFINE` times finer in ``u = log mus`` and ``v = log (mua / mus)`` (:func:`fine_nodes`:
the model E, its Jacobian dE/d(u, v) and its Hessian at each node, cached with the table). A fit
takes the node nearest its start (where the row's previous fits ended, :mod:`.chunk_fit`: neighbours
are alike) and one Gauss-Newton step from the node's model and Jacobian, with the pixel's own ring weights::

    theta = node + A^-1 b,   A = J^T W J,   b = J^T W (E - model)   (at the node)

If ``theta`` lies beyond the node's neighbours, the step is taken again from the node nearest
it (at most :data:`NODE_STEPS` steps). Once it lands within a node of the node it started from
(1.5 node spacings at most: 0.029 in u, 0.054 in v), one more Gauss-Newton step is taken at
``theta`` itself, from the node nearest it (half a node spacing at most): its Jacobian there the
node's plus the node's Hessian times the offset (each node holds the Hessian of E, central
differences of its neighbours' Jacobians), its model the node's plus the offset times the mean of
the two Jacobians (the trapezoid rule: exact to second order); the covariance is ``A^-1`` there
and chi2 the quadratic model's after that step. The node's tangent alone left errors of about
6 d^2 in u (0.16 of a standard error at 1 % noise per ring, steps within half a node).

The second step read the Jacobian interpolated bilinearly between the four nodes around
``theta`` before: one node's six values instead made a fit 109 -> 102 ns on a cache-resident
chunk (``benchmarks/bench_chunk.py``, one thread), as exact. On the benchmark's map
(``benchmarks/bench_optics.py``, 3 % noise per response) 2000 fits lie within 0.0025 standard
errors of the exact minimum of the splines' chi2 (99 % within 0.0011; bilinearly 0.0027 and
0.0017; the full fit's within 0.010), their standard errors within 0.44 % of the minimum's. The
Taylor expansion about the start node itself, whose values are known before the first step ends,
was faster still (93 ns) but 4 times less exact (0.012 of a standard error; standard errors up to
1.4 % off the full fit's at 5 % noise per ring).

A fit whose steps do not settle, that nears the table's edge, or that has no start (a row's first)
is the full Levenberg-Marquardt fit of :mod:`.pixel_fit` (from its coarse search). The fits of a
chunk of a row run together, its pixels as the lanes of vectorised loops (:mod:`.chunk_fit`).
"""

from __future__ import annotations

import math
import weakref

import numba
import numpy as np

from .table import ProfileTable, catmull_rom

REFINE = (4, 4)
"""Fine nodes per table node in u and in v (spacings 0.019 and 0.036 on the default table: 31 MB
for 8 rings)."""
NODE_STEPS = 4
"""Gauss-Newton steps a fit may take from nodes before it is the full fit."""
SMALLEST_MODEL = 1e-30
"""E below which a node's model is not kept (NaN: fits there are the full fit's, in float64)."""
_FINE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def fine_nodes(table: ProfileTable, refine: tuple[int, int] = REFINE) -> tuple[np.ndarray, float, float, float, float]:
    """The model at the fine nodes: ``(nodes, u0, du, v0, dv)``, ``nodes`` (K', J', 6, R) float32
    holding E, dE/du, dE/dv, d2E/du2, d2E/du dv and d2E/dv2 at ``u = u0 + k du``, ``v = v0 + j dv``,
    spanning the table's spline range (its nodes 1 .. K - 2), ``refine`` (u, v) fine nodes per
    table node. The second derivatives are central differences of the neighbours' first (one-sided
    at the range's edges, where fits are the full fit's; the mixed one the mean of both orders): the
    spline's own are discontinuous at the table's nodes. Made once per table and kept while the
    table lives (31 MB for the default table of 8 rings)."""
    key = tuple(refine)
    cached = _FINE.get(table)
    if cached is not None and key in cached:
        return cached[key]
    fine_u, fine_v = refine
    log_profile = table.log_profile
    count_u = fine_u * (log_profile.shape[0] - 3) + 1
    count_v = fine_v * (log_profile.shape[1] - 3) + 1
    model = np.empty((count_u, count_v, 3, len(table.radii)))
    _fill_nodes(log_profile, fine_u, fine_v, table.du, table.dv, model)
    step_u, step_v = table.du / fine_u, table.dv / fine_v
    nodes = np.empty((count_u, count_v, 6, len(table.radii)), np.float32)
    _fill_hessians(model, step_u, step_v, nodes)
    result = (nodes, table.u0 + table.du, step_u, table.v0 + table.dv, step_v)
    _FINE.setdefault(table, {})[key] = result
    return result


@numba.njit(cache=True)
def _spline_weights(index, refine, count):
    """The spline cell (table node k, 1 .. K - 3) of fine node ``index`` and the Catmull-Rom
    weights there (:func:`.table.catmull_rom`); the last fine node is its last cell's end (t = 1)."""
    cell = min(index // refine, count - 1)
    return 1 + cell, catmull_rom((index - refine * cell) / refine)


@numba.njit(parallel=True, cache=True)
def _fill_nodes(log_profile, fine_u, fine_v, du, dv, nodes):
    """The table's spline (:func:`.table.interpolate`, the same sums) at every fine node, made
    separably: each table row in u is first interpolated in v at every fine v, then those rows in
    u (4 products per ring and node in each pass, where the spline takes 16)."""
    count_u, count_v, rings = log_profile.shape[0], nodes.shape[1], log_profile.shape[2]
    rows = np.empty((count_u, count_v, 2, rings))  # along v: log E and its derivative by v's index
    for j in numba.prange(count_v):
        cell, weights = _spline_weights(j, fine_v, count_v // fine_v)
        for k in range(count_u):
            for r in range(rings):
                value = slope = 0.0
                for b in range(4):
                    node = log_profile[k, cell - 1 + b, r]
                    value += weights[b] * node
                    slope += weights[4 + b] * node
                rows[k, j, 0, r] = value
                rows[k, j, 1, r] = slope
    for i in numba.prange(nodes.shape[0]):
        cell, weights = _spline_weights(i, fine_u, nodes.shape[0] // fine_u)
        for j in range(count_v):
            for r in range(rings):
                value = slope_u = slope_v = 0.0
                for a in range(4):
                    value += weights[a] * rows[cell - 1 + a, j, 0, r]
                    slope_u += weights[4 + a] * rows[cell - 1 + a, j, 0, r]
                    slope_v += weights[a] * rows[cell - 1 + a, j, 1, r]
                model = math.exp(value)
                if model < SMALLEST_MODEL:
                    # float32 holds no relative precision down there: NaN sends such a node's fits to the full fit.
                    model = math.nan
                nodes[i, j, 0, r] = model
                nodes[i, j, 1, r] = model * slope_u / du
                nodes[i, j, 2, r] = model * slope_v / dv


@numba.njit(parallel=True, cache=True)
def _fill_hessians(model, step_u, step_v, nodes):
    """``nodes`` (K', J', 6, R): the fine nodes' ``model`` (E, dE/du, dE/dv) and the Hessian of E
    by central differences of the neighbours' derivatives (one-sided at the grid's edges, as
    ``np.gradient``; the mixed derivative the mean of its two differences)."""
    count_u, count_v = model.shape[0], model.shape[1]
    for i in numba.prange(count_u):
        below, above = max(i - 1, 0), min(i + 1, count_u - 1)
        for j in range(count_v):
            left, right = max(j - 1, 0), min(j + 1, count_v - 1)
            across_u = (above - below) * step_u
            across_v = (right - left) * step_v
            for r in range(model.shape[3]):
                nodes[i, j, 0, r] = model[i, j, 0, r]
                nodes[i, j, 1, r] = model[i, j, 1, r]
                nodes[i, j, 2, r] = model[i, j, 2, r]
                nodes[i, j, 3, r] = (model[above, j, 1, r] - model[below, j, 1, r]) / across_u
                nodes[i, j, 4, r] = 0.5 * ((model[i, right, 1, r] - model[i, left, 1, r]) / across_v
                                           + (model[above, j, 2, r] - model[below, j, 2, r]) / across_u)
                nodes[i, j, 5, r] = (model[i, right, 2, r] - model[i, left, 2, r]) / across_v


# Reassociation lets the compiler vectorise the sums over rings and reciprocals replace divisions:
# 0.42 -> 0.24 us a fit, within 5e-13 of a standard error of the strict order's (no nnan / ninf:
# the fits test for NaN). The full fit it falls back on keeps the strict order by its own flags.
@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract", "arcp", "nsz"})
def node_steps(nodes, node_u0, node_du, node_v0, node_dv, data, weight, c, x, scale, u, v, first, fitted):
    """The node fit of pixel ``x``, channel ``c`` of ``data`` and ``weight`` (C, N, R) from the start
    (``u``, ``v``): node steps until one lands within a node of the node it started from, then the
    step at theta (module docstring); ``first`` steps were taken before (where the previous one
    landed, 0 or 1). Returns the node steps taken (0: none settled, the fit is the full fit's), and
    where they settle fills ``fitted`` (6,) with u, v, Cuu, Cuv, Cvv and chi2."""
    last_k = nodes.shape[0] - 1
    last_j = nodes.shape[1] - 1
    # Node indices are kept two from the fine grid's ends: a fit that nears them is the full fit's
    # (whose status says whether its minimum is at the table's edge).
    k = int(round((u - node_u0) / node_du))
    j = int(round((v - node_v0) / node_dv))
    for step in range(first, NODE_STEPS):
        if k < 2 or j < 2 or k > last_k - 2 or j > last_j - 2:
            return 0
        sums = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        for r in range(data.shape[2]):
            sums = _add_ring(sums, weight[c, x, r], scale * nodes[k, j, 1, r], scale * nodes[k, j, 2, r],
                             data[c, x, r] - scale * nodes[k, j, 0, r])
        a_uu, a_uv, a_vv, b_u, b_v, _ = sums
        determinant, step_u, step_v = normal_step(a_uu, a_uv, a_vv, b_u, b_v)
        if not determinant > 0.0:
            return 0
        u = node_u0 + k * node_du + step_u
        v = node_v0 + j * node_dv + step_v
        next_k = int(round((u - node_u0) / node_du))
        next_j = int(round((v - node_v0) / node_dv))
        if abs(next_k - k) <= 1 and abs(next_j - j) <= 1:
            return step + 1 if step_at_theta(nodes, node_u0, node_du, node_v0, node_dv, next_k, next_j, u, v, data,
                                             weight, c, x, scale, fitted) else 0
        k, j = next_k, next_j
    return 0


@numba.njit(cache=True, inline="always")
def step_at_theta(nodes, node_u0, node_du, node_v0, node_dv, k, j, u, v, data, weight, c, x, scale, fitted):
    """The last Gauss-Newton step, at theta = (``u``, ``v``) from node (``k``, ``j``) nearest it
    (:func:`_step_at`), of pixel ``x``, channel ``c`` of ``data`` and ``weight`` (C, N, R): fills
    ``fitted`` (6,) with u, v, Cuu, Cuv, Cvv and chi2 and returns True, or False where the
    normal equations there are singular."""
    a_uu, a_uv, a_vv, b_u, b_v, chi2 = _step_at(nodes, k, j, u - (node_u0 + k * node_du), v - (node_v0 + j * node_dv),
                                                 data, weight, c, x, scale)
    determinant, step_u, step_v = normal_step(a_uu, a_uv, a_vv, b_u, b_v)
    if not determinant > 0.0:
        return False
    fitted[0] = u + step_u
    fitted[1] = v + step_v
    fitted[2] = a_vv / determinant
    fitted[3] = -a_uv / determinant
    fitted[4] = a_uu / determinant
    fitted[5] = max(chi2 - (step_u * b_u + step_v * b_v), 0.0)
    return True


@numba.njit(cache=True, inline="always")
def normal_step(a_uu, a_uv, a_vv, b_u, b_v):
    """``(det A, step_u, step_v)``: the Gauss-Newton step ``A^-1 b`` of the 2 x 2 normal equations
    ``A = [[a_uu, a_uv], [a_uv, a_vv]]``, ``b = (b_u, b_v)``; the step is meaningless unless
    ``det A > 0``."""
    determinant = a_uu * a_vv - a_uv * a_uv
    return (determinant, (a_vv * b_u - a_uv * b_v) / determinant, (a_uu * b_v - a_uv * b_u) / determinant)


@numba.njit(cache=True, inline="always")
def _step_at(nodes, k, j, step_u, step_v, data, weight, c, x, scale):
    """``(A_uu, A_uv, A_vv, b_u, b_v, chi2)`` at theta, offset ``step`` (u, v) from node (``k``,
    ``j``), of pixel ``x``, channel ``c`` of ``data`` and ``weight`` (C, N, R): the Jacobian there
    the node's plus its Hessian times the offset, the model there the node's plus the offset times
    the mean of the two Jacobians (the trapezoid rule: exact to second order, where the node's
    tangent alone left errors of 6 d^2 in u, 0.16 of a standard error at 1 % noise)."""
    sums = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for r in range(weight.shape[2]):
        node_u = nodes[k, j, 1, r]
        node_v = nodes[k, j, 2, r]
        j_u = node_u + nodes[k, j, 3, r] * step_u + nodes[k, j, 4, r] * step_v
        j_v = node_v + nodes[k, j, 4, r] * step_u + nodes[k, j, 5, r] * step_v
        model = scale * (nodes[k, j, 0, r] + 0.5 * ((node_u + j_u) * step_u + (node_v + j_v) * step_v))
        sums = _add_ring(sums, weight[c, x, r], scale * j_u, scale * j_v, data[c, x, r] - model)
    return sums


@numba.njit(cache=True, inline="always")
def _add_ring(sums, weight, j_u, j_v, residual):
    """``sums`` (A_uu, A_uv, A_vv, b_u, b_v, chi2) with one ring's terms added: its ``weight``,
    Jacobian (``j_u``, ``j_v``) and ``residual`` (a tuple, kept in registers)."""
    a_uu, a_uv, a_vv, b_u, b_v, chi2 = sums
    return (a_uu + weight * j_u * j_u, a_uv + weight * j_u * j_v, a_vv + weight * j_v * j_v,
            b_u + weight * j_u * residual, b_v + weight * j_v * residual, chi2 + weight * residual * residual)
