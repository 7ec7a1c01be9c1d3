"""A region's measured ring-light profile and its standard error, per lit point.

For each lit point ``q`` of the region, its own profile ``P_q(r)`` is the weighted mean of its
impulse image over the ring of radius ``r`` around ``q`` (members inside the grid and observed; the
rings of :func:`ringlight.core.rings.geometry.ring_geometry`). Over a laterally homogeneous
region the mean of ``P_q(r)`` over lit points is the region mean of E_r, and its standard error
is the spread of ``P_q(r)`` over the ``m`` lit points divided by ``sqrt(m)``: the ring members'
spread, lit point by lit point. Light common to every lit point (a simulator's shared kernel)
does not show in that spread; the fit adds a floor for it (:mod:`.fit`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..rings.geometry import ring_geometry


@dataclass(frozen=True)
class MeasuredProfile:
    """``mean`` and ``standard_error`` (R, C) of the region-mean E_r at ``radii`` (R,), over
    ``points`` lit points."""

    radii: np.ndarray
    mean: np.ndarray
    standard_error: np.ndarray
    points: int


def measured_profile(dataset: ImpulseDataset, region: np.ndarray, radii, thickness: float = 1.0,
                     antialias: bool = False) -> MeasuredProfile:
    """The profile of the lit points in ``region`` ((H, W) bool) at ``radii`` (within max_radius)."""
    width = dataset.grid_shape[1]
    index = {(int(dy), int(dx)): k for k, (dy, dx) in enumerate(dataset.offsets)}
    qy, qx = np.nonzero(region & dataset.lit)
    if len(qy) < 2:
        raise ValueError("the region holds fewer than 2 lit points")
    rings = []
    for radius in radii:
        ring = ring_geometry(float(radius), thickness, antialias)
        # The response of q at p = q + d is stored at p under the offset q - p = -d.
        ks = [index.get((-int(dy), -int(dx))) for dy, dx in ring.offsets]
        if None in ks:
            raise ValueError(f"ring of radius {radius} reaches beyond the dataset's max_radius")
        rings.append((ring, ks))
    reach = int(np.ceil(max(ring.outer_radius for ring, _ in rings)))
    total = np.zeros((len(radii), len(qy), 3))
    weights = np.zeros((len(radii), len(qy)))
    for row0, row1 in dataset.bands():
        if row1 <= qy.min() - reach or row0 > qy.max() + reach:
            continue
        block = dataset.rows(row0, row1)
        for row, (ring, ks) in enumerate(rings):
            for (dy, dx), weight, k in zip(ring.offsets, ring.weights, ks):
                py, px = qy + dy, qx + dx
                inside = (py >= row0) & (py < row1) & (px >= 0) & (px < width)
                inside[inside] &= dataset.observed[py[inside], px[inside]]
                total[row, inside] += weight * block[py[inside] - row0, px[inside], k]
                weights[row, inside] += weight
    with np.errstate(invalid="ignore", divide="ignore"):
        profiles = (total / weights[..., None]).transpose(1, 0, 2)
    counts = np.isfinite(profiles).sum(axis=0)
    mean = np.nanmean(profiles, axis=0)
    spread = np.nanstd(profiles, axis=0, ddof=1)
    return MeasuredProfile(np.asarray(radii, np.float64), mean, spread / np.sqrt(counts), int(len(qy)))
