"""Ring light images and their standard errors from the ring spread, in one pass over the responses.

:func:`ringlight.core.rings.stacks.ring_stack` and :func:`ringlight.core.rings.noise.stack_noise`
read the response array once each, and the spread's kernel handles weights, per-offset validity
flags and the luminance too. A fit that wants both E_r and SE(E_r) of default rings (weights 1:
the optical-property maps) gets them here from one compiled pass per pixel that sums each distance
group's members and their squares::

    E_r = sum_g S_g / N,    SE(E_r)^2 = sum_g (Q_g - S_g^2 / n_g) / (sum_g (n_g - 1) N)

(S_g, Q_g the sum of the n_g valid members of distance group g and of their squares; groups of
fewer than 2 members add nothing but their members to N; :mod:`.noise` gives the estimator), the
same quantities as the two functions to float rounding (``tests/test_stack_spread.py``). The
sums are float64: the one-pass variance loses about 1e-16 of the members' mean square to
cancellation, 1e-10 of the variance at 0.1 % noise per member. The pass is made row by row
(:func:`spread_row`), so that a caller can use each row at once: the maps fit it while it is in
cache (:mod:`ringlight.core.optics.one_pass`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback
from .members import ring_members, unit_weight_rings
from .radii import as_radii, check_reach
from .stacks import Stack, _ring_tables


def ring_stack_and_errors(dataset: ImpulseDataset, radii, progress: ProgressCallback | None = None
                          ) -> tuple[Stack, np.ndarray]:
    """Default rings (thickness 1, weights 1) at ``radii`` (grid steps): their images and the
    standard errors of those from the spread of each ring's members, as ``ring_stack(dataset,
    radii)`` and ``stack_noise(dataset, radii).ring`` give them for a dataset without replicates.

    Returns ``(stack, errors)``: the :class:`~ringlight.core.rings.stacks.Stack` and (n, H, W, 3)
    float32 standard errors, NaN where a ring has no distance group of 2 valid members.
    ``progress(fraction)`` after each band (may raise ``Cancelled``).
    """
    radii = as_radii(radii)
    rings = spread_rings(dataset, radii)
    height, width = dataset.grid_shape
    images = np.empty((len(radii), height, width, 3), np.float32)
    errors = np.empty((len(radii), height, width, 3), np.float32)
    counts = np.empty((len(radii), height, width), np.int32)
    for row0, row1 in dataset.bands():
        counts[:, row0:row1] = band_members(dataset, rings, row0, row1)
        _stack_spread_kernel(np.ascontiguousarray(dataset.rows(row0, row1)), row0, *rings.kernel_arguments,
                             counts[:, row0:row1], images[:, row0:row1], errors[:, row0:row1])
        if progress is not None:
            progress(row1 / height)
    stack = Stack("ring", radii, 1.0, False, dataset.colorspace, images, counts)
    return stack, errors


@dataclass(frozen=True, eq=False)
class SpreadRings:
    """Default rings on a dataset's offset axis, as :func:`spread_row` reads them.

    Attributes
    ----------
    tables
        The rings' runs and weights (:func:`.stacks._ring_tables`).
    unweighted
        (n,) bool: every default ring's weights are 1.
    kernel_arguments
        ``(lit, dy, dx, first, stop, groups, ring_groups)``: the (H, W) uint8 lit points, the
        offsets (K,) int, the rings' runs ``[first, stop)`` (n,) and their distance ``groups``
        (G, 2) of ring j ``ring_groups[j] .. ring_groups[j + 1]`` (:func:`_ring_distance_groups`).
    """

    tables: tuple
    unweighted: np.ndarray
    kernel_arguments: tuple


def spread_rings(dataset: ImpulseDataset, radii: np.ndarray) -> SpreadRings:
    """The default rings at ``radii`` (grid steps, checked within the dataset's reach) for
    :func:`spread_row`: made once per pass."""
    check_reach(dataset, radii, 0.0, 1.0, False)
    tables = _ring_tables(dataset, radii, 1.0, False)
    first, stop = tables[0], tables[1]
    groups, ring_groups = _ring_distance_groups(dataset.offsets, first, stop)
    lit = np.ascontiguousarray(dataset.lit, np.uint8)
    dy = np.ascontiguousarray(dataset.offsets[:, 0])
    dx = np.ascontiguousarray(dataset.offsets[:, 1])
    return SpreadRings(tables, unit_weight_rings(tables), (lit, dy, dx, first, stop, groups, ring_groups))


def band_members(dataset: ImpulseDataset, rings: SpreadRings, row0: int, row1: int) -> np.ndarray:
    """(n, row1 - row0, W) int32 members of each ring at the band's points
    (:func:`.members.ring_members`: 0 at unobserved points)."""
    counts, _ = ring_members(dataset.lit, dataset.observed, dataset.offsets, rings.tables, rings.unweighted, row0, row1)
    return counts


def _ring_distance_groups(offsets: np.ndarray, first: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rings' runs split into runs of equal distance (the offset axis is sorted by distance):
    ``groups`` (G, 2) each group's bounds ``[start, stop)`` on the offset axis and ``ring_groups``
    (n + 1,): ring j's groups are ``ring_groups[j] .. ring_groups[j + 1]``."""
    squared = (offsets.astype(np.int64) ** 2).sum(axis=1)
    groups, ring_groups = [], [0]
    for low, high in zip(first.tolist(), stop.tolist()):
        if high > low:
            bounds = np.concatenate([[low], low + np.flatnonzero(np.diff(squared[low:high])) + 1, [high]])
            groups.extend(zip(bounds[:-1].tolist(), bounds[1:].tolist()))
        ring_groups.append(len(groups))
    return np.asarray(groups, np.int64).reshape(-1, 2), np.asarray(ring_groups, np.int64)


@numba.njit(cache=True, inline="always")
def _four_sums(pixel, i):
    """Sums of the four members ``pixel[i:i + 12]`` (interleaved R, G, B) and of their squares per
    channel, each as a tree of pairs (a chain of two additions, not four)."""
    a0, b0, c0 = np.float64(pixel[i]), np.float64(pixel[i + 1]), np.float64(pixel[i + 2])
    a1, b1, c1 = np.float64(pixel[i + 3]), np.float64(pixel[i + 4]), np.float64(pixel[i + 5])
    a2, b2, c2 = np.float64(pixel[i + 6]), np.float64(pixel[i + 7]), np.float64(pixel[i + 8])
    a3, b3, c3 = np.float64(pixel[i + 9]), np.float64(pixel[i + 10]), np.float64(pixel[i + 11])
    return ((a0 + a1) + (a2 + a3), (b0 + b1) + (b2 + b3), (c0 + c1) + (c2 + c3),
            (a0 * a0 + a1 * a1) + (a2 * a2 + a3 * a3), (b0 * b0 + b1 * b1) + (b2 * b2 + b3 * b3),
            (c0 * c0 + c1 * c1) + (c2 * c2 + c3 * c3))


@numba.njit(cache=True, inline="always", fastmath={"reassoc", "contract"})
def _whole_group_sums(pixel, start, end):
    """Sums of the members ``pixel[start:end]`` (interleaved R, G, B) and of their squares per
    channel. A distance group holds 1, 4 or 8 members (more only where two lattice distances
    coincide, 5 = 3-4-5): one pass over them, without the stack's partial sums
    (:data:`~.stacks.LANES`), whose set-up and reduction per group cost more than the group's sums
    (the errors beyond the stack, in CPU time over the stack's, max_radius 8, both kernels
    alternating in one process: 1.00 x with them, 0.23 x without on a 500 x 500 grid, one thread;
    1.04-1.21 x and 0.67-0.78 x on 800 x 800; the same sums to the bit). Groups of 4 and 8 are
    summed as trees of pairs (:func:`_four_sums`), written out: on a cache-resident 64-pixel chunk,
    one thread, :func:`spread_row` took 150 ns a pixel channel with them, 167 without, and 168
    with a loop over fours for any size (the same sums to the bit on the benchmark's map)."""
    if end - start == 12:
        return _four_sums(pixel, start)
    if end - start == 24:
        s0, s1, s2, z0, z1, z2 = _four_sums(pixel, start)
        t0, t1, t2, y0, y1, y2 = _four_sums(pixel, start + 12)
        return s0 + t0, s1 + t1, s2 + t2, z0 + y0, z1 + y1, z2 + y2
    s0 = s1 = s2 = z0 = z1 = z2 = 0.0
    for i in range(start, end, 3):
        a, b, c = np.float64(pixel[i]), np.float64(pixel[i + 1]), np.float64(pixel[i + 2])
        s0 += a
        s1 += b
        s2 += c
        z0 += a * a
        z1 += b * b
        z2 += c * c
    return s0, s1, s2, z0, z1, z2


@numba.njit(cache=True, inline="always")
def _lit_group_sums(pixel, start, end, lit, py, px, dy, dx):
    """Members of offsets ``start .. end`` whose lit point is inside the grid and lit: their number
    and, as :func:`_whole_group_sums`, their sums and sums of squares per channel."""
    height, width = lit.shape
    n = 0
    s0 = s1 = s2 = z0 = z1 = z2 = 0.0
    for k in range(start, end):
        qy = py + dy[k]
        qx = px + dx[k]
        if qy < 0 or qy >= height or qx < 0 or qx >= width or lit[qy, qx] == 0:
            continue
        a, b, c = np.float64(pixel[3 * k]), np.float64(pixel[3 * k + 1]), np.float64(pixel[3 * k + 2])
        s0 += a
        s1 += b
        s2 += c
        z0 += a * a
        z1 += b * b
        z2 += c * c
        n += 1
    return n, s0, s1, s2, z0, z1, z2


@numba.njit(parallel=True, cache=True, nogil=True)
def _stack_spread_kernel(responses, row0, lit, dy, dx, first, stop, groups, ring_groups, counts, images, errors):
    """Fill ``images`` and ``errors`` (n, rows, W, 3) of the band of grid rows from ``row0``, from its
    ``responses`` (rows, W, K, 3) C-contiguous and the members' ``counts`` (n, rows, W), row by row
    (:func:`spread_row`; the other arguments are :attr:`SpreadRings.kernel_arguments`)."""
    rows, width, offsets = responses.shape[0], responses.shape[1], responses.shape[2]
    flat = responses.reshape(rows, width, offsets * 3)
    for y in numba.prange(rows):
        spread_row(flat[y], row0 + y, 0, lit, dy, dx, first, stop, groups, ring_groups, counts[:, y], images[:, y],
                   errors[:, y])


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def spread_row(pixels, py, px, lit, dy, dx, first, stop, groups, ring_groups, counts, images, errors):
    """Fill ``images`` and ``errors`` (n, W, 3) of W pixels of grid row ``py`` from column ``px``
    from their responses ``pixels`` (W, K * 3: each offset's R, G, B), the (H, W) uint8 ``lit`` points, the offsets ``dy``,
    ``dx`` (K,), the rings' runs ``first``, ``stop`` (n,), their distance ``groups`` (G, 2) (offset
    bounds) of ring j ``ring_groups[j] .. ring_groups[j + 1]`` and the members' ``counts`` (n, W)
    (:func:`.members.ring_members`: 0 at unobserved points).

    A pixel all of whose rings are whole (counts equal the runs' lengths) reads no validity: every
    member is inside the grid and lit. Elsewhere a member counts when its lit point is inside the
    grid and lit (its response is 0 otherwise, by the dataset's invariant, so sums need no flag).
    """
    width = pixels.shape[0]
    rings = first.size
    # A pixel's SE^2, ring by ring (3 j + channel), square-rooted together after its last ring: a
    # loop the compiler vectorises, where a root per ring and channel was an eighth of the pass
    # (cache-resident chunk, one thread: 150 -> 140 ns a pixel channel; the same roots to the bit).
    variances = np.empty(3 * rings)
    # 1 / n of each whole distance group, made once per call: a division per group and pixel was 5 %
    # of the pass (cache-resident chunk, one thread, bench_chunk.py: 140-147 -> 134 ns a pixel
    # channel; the same reciprocals, the same errors to the bit).
    inverses = np.empty(groups.shape[0])
    for g in range(groups.shape[0]):
        inverses[g] = 1.0 / (groups[g, 1] - groups[g, 0])  # a group holds a member at least
    for x in range(width):
        pixel = pixels[x]
        whole = True
        for j in range(rings):
            if counts[j, x] != stop[j] - first[j]:
                whole = False
        for j in range(rings):
            if counts[j, x] == 0:
                for channel in range(3):
                    images[j, x, channel] = np.nan
                    variances[3 * j + channel] = np.nan
                continue
            t0 = t1 = t2 = 0.0
            q0 = q1 = q2 = 0.0
            dof = 0.0
            members = 0
            for g in range(ring_groups[j], ring_groups[j + 1]):
                if whole:
                    n = groups[g, 1] - groups[g, 0]
                    s0, s1, s2, z0, z1, z2 = _whole_group_sums(pixel, 3 * groups[g, 0], 3 * groups[g, 1])
                else:
                    n, s0, s1, s2, z0, z1, z2 = _lit_group_sums(pixel, groups[g, 0], groups[g, 1], lit, py, px + x, dy,
                                                                dx)
                t0 += s0
                t1 += s1
                t2 += s2
                members += n
                if n >= 2:
                    # A reciprocal, not three divisions: a division per channel and group was a tenth
                    # of the pass (the errors beyond the stack 0.46 -> 0.31 x, 600 x 600, max_radius 8).
                    inverse = inverses[g] if whole else 1.0 / n
                    q0 += z0 - s0 * s0 * inverse
                    q1 += z1 - s1 * s1 * inverse
                    q2 += z2 - s2 * s2 * inverse
                    dof += n - 1.0
            images[j, x, 0] = t0 / members
            images[j, x, 1] = t1 / members
            images[j, x, 2] = t2 / members
            if dof == 0.0:
                variances[3 * j] = np.nan
                variances[3 * j + 1] = np.nan
                variances[3 * j + 2] = np.nan
                continue
            # SE^2 = s^2 / N, s^2 pooled within the groups (unit weights: V1 = V2 = N).
            factor = 1.0 / (dof * members)
            variances[3 * j] = max(q0, 0.0) * factor
            variances[3 * j + 1] = max(q1, 0.0) * factor
            variances[3 * j + 2] = max(q2, 0.0) * factor
        for i in range(3 * rings):
            variances[i] = math.sqrt(variances[i])
        for j in range(rings):
            errors[j, x, 0] = variances[3 * j]
            errors[j, x, 1] = variances[3 * j + 1]
            errors[j, x, 2] = variances[3 * j + 2]
