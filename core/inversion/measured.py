"""A region's measured ring-light profile and its standard error, per lit point.

For each lit point ``q`` of the region, its own profile ``P_q(r)`` is the weighted mean of its
impulse image over the ring of radius ``r`` around ``q`` (members inside the grid and observed; the
rings of :func:`ringlight.core.rings.geometry.ring_geometry`). Over a laterally homogeneous
region the mean of ``P_q(r)`` over lit points is the region mean of E_r, and its standard error
is the spread of ``P_q(r)`` over the ``m`` lit points divided by ``sqrt(m)``: the ring members'
spread, lit point by lit point. Light common to every lit point (a simulator's shared kernel)
does not show in that spread; the fit adds a floor for it (:mod:`.fit`). A dataset that holds
independent replicates of its capture measures that noise too: there the standard error is the
spread of the region's profile over the replicates, with the channels' covariance.

A ring cut by the grid's edge (or by unobserved pixels) keeps the members left, renormalised: its
mean leans toward the members that remain, and a ring's members lie at different distances (at
r = 1: 1 and sqrt 2). Averaged over a region with edge points this moves the mean by up to 1 % at
r = 1 on a 24 x 24 grid. So the profile also carries each ring's *effective* weights: the mean over
the region's lit points of the renormalised weights each offset got. For a laterally homogeneous
region (impulse response ``I(d)`` at offset ``d`` for every lit point) the measured mean is exactly
``sum_d weight_d I(d)``, and the forward model (:class:`.forward.Forward`) uses these weights.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset, open_dataset
from ..dataset.replicates import replicate_manifests
from ..rings.geometry import ring_geometry
from .fit import RELATIVE_FLOOR
from .settings import InversionError


@dataclass(frozen=True)
class MeasuredProfile:
    """``mean`` and ``standard_error`` (R, C) of the region-mean E_r at ``radii`` (R,), over
    ``points`` lit points. ``ring_weights`` (R, S, S), S odd: each ring's effective weight of the
    pixel offset ``[dy + S // 2, dx + S // 2]`` (each row sums to 1), or None for whole rings.

    From a dataset of ``replicates`` > 1, the standard error and ``covariance`` (R, C, C) between
    the channels are the replicates' spread, which holds the noise the lit points share, and the
    fit's relative ``floor`` for that noise is 0; else ``covariance`` is None and ``floor`` is
    :data:`.fit.RELATIVE_FLOOR`."""

    radii: np.ndarray
    mean: np.ndarray
    standard_error: np.ndarray
    points: int
    ring_weights: np.ndarray | None = None
    covariance: np.ndarray | None = None
    replicates: int = 1
    floor: float = RELATIVE_FLOOR


def measured_profile(dataset: ImpulseDataset, region: np.ndarray, radii, thickness: float = 1.0,
                     antialias: bool = False) -> MeasuredProfile:
    """The profile of the lit points in ``region`` ((H, W) bool) at ``radii`` (within max_radius).

    The standard error is the spread of the lit points' own profiles, or, for a dataset of two or
    more replicates, of the replicates' profiles (:func:`replicate_profile`).

    Raises :class:`.settings.InversionError` naming the dataset when the region is not of the
    grid's shape or holds fewer than 2 lit points (no spread, so no standard error), or when there
    are no radii or a ring reaches beyond max_radius."""
    if np.shape(region) != tuple(dataset.grid_shape):
        raise InversionError(f"{dataset.path}: the region is {np.shape(region)}, not the grid's "
                             f"{tuple(dataset.grid_shape)}")
    if len(radii) == 0:
        raise InversionError(f"{dataset.path}: max_radius {dataset.max_radius:g} holds no ring to measure a profile at "
                             "(r = 0 needs 0.5)")
    index = {(int(dy), int(dx)): k for k, (dy, dx) in enumerate(dataset.offsets)}
    qy, qx = np.nonzero(region & dataset.lit)
    if len(qy) < 2:
        raise InversionError(f"{dataset.path}: the region holds {len(qy)} lit point(s); a profile's standard error "
                             "needs at least 2: choose a larger region")
    rings = []
    for radius in radii:
        ring = ring_geometry(float(radius), thickness, antialias)
        # The response of q at p = q + d is stored at p under the offset q - p = -d.
        ks = [index.get((-int(dy), -int(dx))) for dy, dx in ring.offsets]
        if None in ks:
            raise InversionError(f"{dataset.path}: a ring of radius {radius:g} reaches beyond the dataset's "
                                 f"max_radius {dataset.max_radius:g}")
        rings.append((ring, ks))
    reach = int(np.ceil(max(ring.outer_radius for ring, _ in rings)))
    # Every ring's members, one after another: ring ``row``'s are ``first[row]:first[row + 1]``.
    first = np.cumsum([0] + [len(ks) for _, ks in rings])
    member_offsets = np.concatenate([np.asarray(ring.offsets, np.int64).reshape(-1, 2) for ring, _ in rings])
    member_weights = np.concatenate([np.asarray(ring.weights, np.float64) for ring, _ in rings])
    member_k = np.concatenate([np.asarray(ks, np.int64) for _, ks in rings])
    total = np.zeros((len(radii), len(qy), 3))
    weights = np.zeros((len(radii), len(qy)))
    observed = np.ascontiguousarray(dataset.observed)
    for row0, row1 in dataset.bands():
        if row1 <= qy.min() - reach or row0 > qy.max() + reach:
            continue
        _add_members(dataset.rows(row0, row1), row0, qy, qx, first, member_offsets, member_weights, member_k,
                     observed, total, weights)
    with np.errstate(invalid="ignore", divide="ignore"):
        profiles = (total / weights[..., None]).transpose(1, 0, 2)
    counts = np.isfinite(profiles).sum(axis=0)
    mean = np.nanmean(profiles, axis=0)
    spread = np.nanstd(profiles, axis=0, ddof=1)
    effective = _effective_weights(dataset, qy, qx, rings, weights, np.isfinite(profiles).all(axis=2).T, reach)
    measured = MeasuredProfile(np.asarray(radii, np.float64), mean, spread / np.sqrt(counts), int(len(qy)), effective)
    if len(dataset.manifest.replicates) > 1:
        return replicate_profile(dataset, region, measured, thickness, antialias)
    return measured


def replicate_profile(dataset: ImpulseDataset, region: np.ndarray, measured: MeasuredProfile, thickness: float,
                      antialias: bool) -> MeasuredProfile:
    """``measured`` (the dataset's profile) with its standard error and channel covariance from the
    spread of the region's profile over the dataset's ``K`` replicates, each opened on its own
    (:mod:`ringlight.core.dataset.replicates`): ``cov_k(P_k) / K`` per ring, ddof 1, and no floor."""
    profiles = []
    for manifest in replicate_manifests(dataset.manifest):
        replicate = open_dataset(manifest, radius=dataset.max_radius, use_cache=False)
        profiles.append(measured_profile(replicate, region, measured.radii, thickness, antialias).mean)
    profiles = np.stack(profiles)  # (K, R, C)
    count = len(profiles)
    centred = profiles - profiles.mean(axis=0)
    covariance = np.einsum("krc,krd->rcd", centred, centred) / (count - 1) / count
    error = np.sqrt(np.diagonal(covariance, axis1=1, axis2=2))
    return replace(measured, standard_error=error, covariance=covariance, replicates=count, floor=0.0)


@numba.njit(cache=True, nogil=True)
def _add_members(block, row0, qy, qx, first, member_offsets, member_weights, member_k, observed, total, weights):
    """Add to ``total`` (R, m, 3) each lit point's ring members' weighted responses found in
    ``block`` (rows ``row0`` on of :meth:`~ringlight.core.dataset.impulse_dataset.ImpulseDataset.rows`:
    (rows, W, offsets, 3)), and their weights to ``weights`` (R, m): members inside the block and
    the grid and observed (``observed`` (H, W) bool). Ring ``row``'s members are
    ``first[row]:first[row + 1]`` of ``member_offsets`` ((M, 2) dy, dx), ``member_weights`` (M,)
    and ``member_k`` (M,), the offset index the response is stored under. The same sums, added in
    the same order (ring by ring, member by member), as numpy over the lit points at each member,
    without a Python step per member (11 367 on layers3: 2.3 CPU-s a profile). A monochrome
    block (one channel) adds its channel to all three, as numpy broadcasts it."""
    rows, width, last = block.shape[0], block.shape[1], block.shape[3] - 1
    for row in range(first.shape[0] - 1):
        for member in range(first[row], first[row + 1]):
            dy, dx = member_offsets[member, 0], member_offsets[member, 1]
            weight, k = member_weights[member], member_k[member]
            for i in range(qy.shape[0]):
                py, px = qy[i] + dy, qx[i] + dx
                if 0 <= py - row0 < rows and 0 <= px < width and observed[py, px]:
                    for c in range(3):
                        total[row, i, c] += weight * block[py - row0, px, k, min(c, last)]
                    weights[row, i] += weight


def _members_inside(dataset: ImpulseDataset, qy, qx, dy: int, dx: int, row0: int, row1: int, width: int):
    """(m,) bool: the ring member ``q + (dy, dx)`` of each lit point lies in rows ``[row0, row1)``,
    inside the grid and observed."""
    py, px = qy + dy, qx + dx
    inside = (py >= row0) & (py < row1) & (px >= 0) & (px < width)
    inside[inside] &= dataset.observed[py[inside], px[inside]]
    return inside


def _effective_weights(dataset: ImpulseDataset, qy, qx, rings, weights: np.ndarray, finite: np.ndarray,
                       reach: int) -> np.ndarray:
    """(R, S, S) each ring's weight per offset, renormalised per lit point as its profile was and
    averaged over the lit points whose profile is finite (``finite`` (R, m)); S = 2 reach + 1."""
    height, width = dataset.grid_shape
    side = 2 * reach + 1
    effective = np.zeros((len(rings), side, side))
    for row, (ring, _) in enumerate(rings):
        used = finite[row] & (weights[row] > 0)
        if not used.any():
            continue
        share = np.zeros(len(qy))
        share[used] = 1.0 / weights[row, used]
        for (dy, dx), weight in zip(ring.offsets, ring.weights):
            inside = _members_inside(dataset, qy, qx, dy, dx, 0, height, width)
            effective[row, dy + reach, dx + reach] += weight * share[inside].sum()
        effective[row] /= used.sum()
    return effective
