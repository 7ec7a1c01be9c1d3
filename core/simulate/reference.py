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
A walk is the same walk in both volumes, with the same scores, until its first tentative
collision in a voxel that differs from the reference or whose next-event path toward the camera
crosses one (:func:`mixed_voxels`); the reference walk takes over from there, and a walk that
never gets there has a difference of exactly zero and no reference walk. For
a layered scene no column differs: the reference is the scene, and one simulation serves every
lit point. Far from the shapes, almost every walk cancels, and the noise of a ring light image is
that of ``K``; the price is one extra walk for each photon that touches a shape. Unbiased for any
choice of reference.
"""

from __future__ import annotations

import math

import numpy as np

from .camera import UNIFORM_MU_T, column_optical_depths, optics
from ..device import Device
from .photon import point_kernels
from .tables import MU_T, channel_count

KERNEL_STREAMS = 64
"""The reference kernel's photons are split into this many random streams."""
KERNEL_TRUTH_BLOCKS = 16
"""Parallel blocks of the kernel's path-length images (summed in order: deterministic)."""


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


def mixed_voxels(volume: np.ndarray, reference: np.ndarray, n: float, camera=(0.0, 0.0)) -> np.ndarray:
    """(D, H, W) bool: the voxels where a walk, or what it scores, can first differ between
    ``volume`` and ``reference``. For a camera straight down, a voxel that differs or lies below
    one in its column (the next-event path goes straight up through it); for an oblique camera,
    every voxel of :func:`mixed_columns`. A walk is the same walk, with the same scores, in both
    volumes until its first tentative collision in a marked voxel."""
    if camera[0] == 0.0:
        return np.logical_or.accumulate(volume != reference, axis=0)
    return np.broadcast_to(mixed_columns(volume, reference, n, camera), volume.shape).copy()


def _pad_shift(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``mask`` moved by ``(dy, dx)``, filled with False (no wrap-around)."""
    out = np.zeros_like(mask)
    height, width = mask.shape
    ys, xs = slice(max(dy, 0), height + min(dy, 0)), slice(max(dx, 0), width + min(dx, 0))
    out[ys, xs] = mask[max(-dy, 0):height - max(dy, 0), max(-dx, 0):width - max(dx, 0)]
    return out


def reference_kernel(reference: np.ndarray, tables: np.ndarray, majorant: float, geometry: np.ndarray, camera: bool,
                     direction, photons: int, seed: int, stream: int, window_radius: int, grid: tuple[int, int],
                     bin_step: float, bin_count: int, symmetric: bool, device: Device | None = None,
                     streams: int = KERNEL_STREAMS) -> tuple[np.ndarray, np.ndarray]:
    """The reference's response to one lit point, ``photons`` photons, for the C channels of
    ``tables`` (:func:`.tables.walk_tables`).

    Returns ``(window, truth)``: (2R+1, 2R+1, C) float64 per photon at offsets
    ``[dy + R, dx + R]``, and (bins, 2H-1, 2W-1, C) float64 per photon at offsets
    ``[dy + H - 1, dx + W - 1]`` by path-length bin (every offset a grid of ``grid = (H, W)``
    can hold). ``symmetric``: average over the symmetries of the square grid that keep the
    shapes (exact when projector and camera look straight down). Random streams
    ``stream .. stream + streams - 1`` of ``seed``, run on ``device`` (the CPU when None).
    """
    channels = channel_count(tables)
    height, width = grid
    centre = np.array([[height - 1, width - 1]] * streams, np.int64)
    size = 2 * window_radius + 1
    window = np.zeros((size, size, channels))
    kernel = np.zeros((bin_count, 2 * height - 1, 2 * width - 1, channels))
    # Spread the photons over the streams; the first ones take the remainder.
    per_stream = np.full(streams, photons // streams)
    per_stream[:photons % streams] += 1
    columns = _columns(reference, tables, camera, direction, geometry)
    simulate_points = point_kernels(device)[0]
    for count in np.unique(per_stream):
        chosen = np.nonzero(per_stream == count)[0]
        if count == 0:
            continue
        part_windows = np.zeros((len(chosen), size, size, channels))
        part_truth = np.zeros((min(KERNEL_TRUTH_BLOCKS, len(chosen)), bin_count, 2 * height - 1, 2 * width - 1,
                               channels))
        simulate_points(reference, tables, majorant, geometry, columns, camera, centre[chosen], int(count), seed,
                        stream + chosen, bin_step, part_windows, part_truth)
        window += part_windows.sum(axis=0)
        kernel += part_truth.sum(axis=0)
    window /= photons
    kernel /= photons
    if symmetric:
        window = _symmetrise(window)
        kernel = _symmetrise(kernel)
    return window, kernel


def _symmetrise(array: np.ndarray) -> np.ndarray:
    """The mean of ``array`` (..., H, W, C) over the flips of its axes H and W, and over their
    transposition too when square."""
    flips = [array, array[..., ::-1, :, :], array[..., :, ::-1, :], array[..., ::-1, ::-1, :]]
    if array.shape[-2] == array.shape[-3]:
        flips += [np.swapaxes(a, -2, -3) for a in flips]
    return sum(flips) / len(flips)


def spread_kernel(kernel: np.ndarray, lit: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """(bins, H, W, C): the sum over lit points ``q`` ((n, 2) ``[y, x]``) of the
    (bins, 2H-1, 2W-1, C) ``kernel`` placed at ``q`` (offset ``[dy + H - 1, dx + W - 1]`` lands
    on ``q + d``)."""
    height, width = grid
    out = np.zeros((kernel.shape[0], height, width) + kernel.shape[3:])
    for qy, qx in lit:
        out += kernel[:, height - 1 - qy:2 * height - 1 - qy, width - 1 - qx:2 * width - 1 - qx]
    return out


def _columns(volume, tables, camera, direction, geometry) -> np.ndarray:
    """The column table of :func:`.camera.column_optical_depths` where the estimate uses one."""
    if camera and geometry[UNIFORM_MU_T] < 0:
        return column_optical_depths(volume, tables[MU_T:MU_T + channel_count(tables)], direction)
    return np.zeros((0, 0, 0, 0))


def simulate_point_differences(volume, reference, mixed, tables, majorant, geometry, reference_geometry, camera,
                               direction, lit, photons, direct, seed, streams, bin_step, windows, truth,
                               device: Device | None = None) -> np.ndarray:
    """:func:`.photon.simulate_differences` with the column tables of both volumes (the channels
    of ``tables``; ``direction`` the camera's ``[zenith, azimuth]``; ``photons`` (n,) and
    ``direct`` (n,) bool per lit point), on ``device`` (the CPU when None). Returns (n,) int64:
    how many of each point's walks reached a marked voxel."""
    columns = _columns(volume, tables, camera, direction, geometry)
    reference_columns = _columns(reference, tables, camera, direction, reference_geometry)
    touches = np.zeros(len(lit), np.int64)
    simulate_differences = point_kernels(device)[1]
    simulate_differences(volume, reference, mixed, tables, majorant, geometry, reference_geometry, columns,
                         reference_columns, camera, lit, np.asarray(photons, np.int64), np.asarray(direct, np.bool_),
                         seed, streams, bin_step, windows, truth, touches)
    return touches


def reference_optics(n: float, depth: float, projector, camera, reference: np.ndarray) -> np.ndarray:
    """The optics array of the reference volume (uniform ``mu_t`` when it is one material)."""
    uniform = len(np.unique(reference)) == 1
    return optics(n, depth, projector, camera, 0.0 if uniform else -1.0)
