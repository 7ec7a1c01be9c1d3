"""Variance reduction by a shift-invariant reference and correlated differences.

A scene is a layered *reference* (the most common material of each depth slice: for the presets,
the layers or the background without the shapes) plus whatever differs from it in some columns
(a bead, a star). Light transport in the reference is shift-invariant: every lit point sees the
same response, shifted. So the response of lit point ``q`` is, exactly,

    R_q = K + E[X_scene - X_reference]

with ``K`` the reference's response, simulated once at the origin with as many photons as all
lit points together (and averaged over the symmetries of the square grid when projector and
camera look straight down, both exact), and the expectation estimated per lit point with the
*same* random numbers for both walks (common random numbers, :func:`.photon.simulate_differences`).
A walk that never has a tentative collision in a column that differs from the reference (and,
for an oblique camera, whose next-event paths cannot cross one) is the same walk in both volumes
with the same scores, so its difference is exactly zero and the reference walk is skipped. For
a layered scene no column differs: the reference is the scene, and one simulation serves every
lit point. Far from the shapes, almost every walk cancels, and the noise of a ring light image is
that of ``K``; the price is one extra walk for each photon that touches a shape. Unbiased for any
choice of reference.
"""

from __future__ import annotations

import math

import numpy as np

from .camera import UNIFORM_MU_T, column_optical_depths, optics
from .photon import simulate_differences, simulate_points

KERNEL_STREAMS = 64
"""The reference kernel's photons are split into this many random streams (the parallel blocks)."""


def reference_volume(volume: np.ndarray) -> np.ndarray:
    """(D, 1, 1) uint8: the most common material of each depth slice of a (D, H, W) volume (the
    voxel volume repeats its edge sideways, so this is a laterally infinite layered medium)."""
    slices = volume.reshape(volume.shape[0], -1)
    modes = np.array([np.bincount(row).argmax() for row in slices], np.uint8)
    return modes.reshape(-1, 1, 1)


def mixed_columns(volume: np.ndarray, reference: np.ndarray, n: float, camera=(0.0, 0.0)) -> np.ndarray:
    """(H, W) bool: the columns where ``volume`` differs from ``reference`` at some depth, grown
    by how far sideways a next-event path toward an oblique camera can travel from below a
    column's deepest differing voxel to the surface (so that an unmarked walk is the same walk,
    with the same scores, in both volumes)."""
    differs = volume != reference
    marked = differs.any(axis=0)
    if camera[0] != 0.0 and marked.any():
        deepest = int(np.nonzero(differs.any(axis=(1, 2)))[0].max()) + 1
        sin_inside = math.sin(math.radians(camera[0])) / n
        reach = math.ceil(deepest * sin_inside / math.sqrt(1.0 - sin_inside * sin_inside)) + 1
        grown = marked.copy()
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                grown |= _pad_shift(marked, dy, dx)
        marked = grown
    return marked


def _pad_shift(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``mask`` moved by ``(dy, dx)``, filled with False (no wrap-around)."""
    out = np.zeros_like(mask)
    height, width = mask.shape
    ys, xs = slice(max(dy, 0), height + min(dy, 0)), slice(max(dx, 0), width + min(dx, 0))
    out[ys, xs] = mask[max(-dy, 0):height - max(dy, 0), max(-dx, 0):width - max(dx, 0)]
    return out


def reference_kernel(reference: np.ndarray, tables, majorant: float, geometry: np.ndarray, camera: bool,
                     direction, photons: int, seed: int, stream: int, window_radius: int, grid: tuple[int, int],
                     bin_step: float, bin_count: int, symmetric: bool) -> tuple[np.ndarray, np.ndarray]:
    """The reference's response to one lit point, ``photons`` photons (one channel).

    Returns ``(window, truth)``: (2R+1, 2R+1) float64 per photon at offsets ``[dy + R, dx + R]``,
    and (bins, 2H-1, 2W-1) float64 per photon at offsets ``[dy + H - 1, dx + W - 1]`` by
    path-length bin (every offset a grid of ``grid = (H, W)`` can hold). ``symmetric``: average
    over the symmetries of the square grid that keep the shapes (exact when projector and camera
    look straight down). Random streams ``stream .. stream + KERNEL_STREAMS - 1`` of ``seed``.
    """
    mu_t, albedo, g = tables
    height, width = grid
    centre = np.array([[height - 1, width - 1]] * KERNEL_STREAMS, np.int64)
    size = 2 * window_radius + 1
    windows = np.zeros((KERNEL_STREAMS, size, size))
    truth = np.zeros((KERNEL_STREAMS, bin_count, 2 * height - 1, 2 * width - 1))
    # Spread the photons over the streams; the first ones take the remainder.
    per_stream = np.full(KERNEL_STREAMS, photons // KERNEL_STREAMS)
    per_stream[:photons % KERNEL_STREAMS] += 1
    columns = _columns(reference, mu_t, camera, direction, geometry)
    for count in np.unique(per_stream):
        chosen = np.nonzero(per_stream == count)[0]
        if count == 0:
            continue
        part_windows = np.zeros((len(chosen), size, size))
        part_truth = np.zeros((len(chosen), bin_count, 2 * height - 1, 2 * width - 1))
        simulate_points(reference, mu_t, albedo, g, majorant, geometry, columns, camera, centre[chosen], int(count),
                        seed, stream + chosen, bin_step, part_windows, part_truth)
        windows[chosen] = part_windows
        truth[chosen] = part_truth
    window = windows.sum(axis=0) / photons
    kernel = truth.sum(axis=0) / photons
    if symmetric:
        window = _symmetrise(window)
        kernel = _symmetrise(kernel)
    return window, kernel


def _symmetrise(array: np.ndarray) -> np.ndarray:
    """The mean of ``array`` (..., H, W) over the flips of its last two axes, and over their
    transposition too when square."""
    flips = [array, array[..., ::-1, :], array[..., :, ::-1], array[..., ::-1, ::-1]]
    if array.shape[-1] == array.shape[-2]:
        flips += [np.swapaxes(a, -1, -2) for a in flips]
    return sum(flips) / len(flips)


def spread_kernel(kernel: np.ndarray, lit: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """(bins, H, W): the sum over lit points ``q`` ((n, 2) ``[y, x]``) of the (bins, 2H-1, 2W-1)
    ``kernel`` placed at ``q`` (offset ``[dy + H - 1, dx + W - 1]`` lands on ``q + d``)."""
    height, width = grid
    out = np.zeros((kernel.shape[0], height, width))
    for qy, qx in lit:
        out += kernel[:, height - 1 - qy:2 * height - 1 - qy, width - 1 - qx:2 * width - 1 - qx]
    return out


def _columns(volume, mu_t, camera, direction, geometry) -> np.ndarray:
    """The column table of :func:`.camera.column_optical_depths` where the estimate uses one."""
    if camera and geometry[UNIFORM_MU_T] < 0:
        return column_optical_depths(volume, mu_t, direction)
    return np.zeros((0, 0, 0))


def simulate_point_differences(volume, reference, mixed, tables, majorant, geometry, reference_geometry, camera,
                               direction, lit, photons, seed, streams, bin_step, windows, truth) -> None:
    """:func:`.photon.simulate_differences` with the column tables of both volumes (one channel;
    ``direction`` the camera's ``[zenith, azimuth]``)."""
    mu_t, albedo, g = tables
    columns = _columns(volume, mu_t, camera, direction, geometry)
    reference_columns = _columns(reference, mu_t, camera, direction, reference_geometry)
    simulate_differences(volume, reference, mixed, mu_t, albedo, g, majorant, geometry, reference_geometry, columns,
                         reference_columns, camera, lit, photons, seed, streams, bin_step, windows, truth)


def reference_optics(n: float, depth: float, projector, camera, mu_t: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The optics array of the reference volume (uniform ``mu_t`` when it is one material)."""
    used = np.unique(reference)
    uniform_mu_t = float(mu_t[used[0]]) if len(used) == 1 else -1.0
    return optics(n, depth, projector, camera, uniform_mu_t)
