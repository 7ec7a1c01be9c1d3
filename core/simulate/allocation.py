"""Sharing the correlated-difference photons among lit points (Neyman allocation).

In the reference estimator (:mod:`.reference`) a lit point's difference walk costs one walk, and
a second when it reaches a voxel where the scene differs from the reference; only those that do
score anything, and all the noise is theirs. Once they part, the scene's walk and the
reference's are as good as independent, so with ``p`` the fraction of a point's walks that
reach such a voxel, the variance of its mean difference per photon is about ``2 p V`` (``V`` that
of one walk scored whole) at a cost of ``1 + p`` per photon. Scoring the point's walks whole
instead (its response directly, without the reference kernel) costs 1 for a variance ``V``; that
is the better buy when ``2 p (1 + p) > 1``, ``p`` above :data:`DIRECT_REACH` (points on or next
to a shape). For the least total variance at a given cost, each point then gets photons in
proportion to the square root of variance over cost (Neyman's allocation): ``sqrt(p / (1 + p))``
for a difference, ``sqrt(1 / 2)`` for a direct point. Unbiased whatever the shares: each point's
mean is over its own photons.

``p`` comes from a pilot of :data:`PILOT_PHOTONS` walks per point (its scores discarded; its own
random streams of the scene's seed, so every run of a scene shares one allocation), averaged over
each point's lit 3 x 3 grid neighbours (``p`` varies smoothly with the point). Every point keeps at
least :data:`FLOOR` of the largest share, so that rare walks a small pilot did not see are still
found; the shares are scaled so that the expected cost equals that of ``photons`` for every point.
"""

from __future__ import annotations

import math

import numpy as np

PILOT_PHOTONS = 8
FLOOR = 0.1
DIRECT_REACH = (math.sqrt(3.0) - 1.0) / 2.0
"""The reach fraction above which scoring a point's walks whole beats differences (0.366)."""


def reach_fractions(touches: np.ndarray, lit: np.ndarray, grid: tuple[int, int], photons: int) -> np.ndarray:
    """(n,) the fraction of walks of each lit point (``lit`` (n, 2) ``[y, x]``) that reached a
    marked voxel, ``touches`` (n,) of ``photons`` each, averaged over its lit 3 x 3 neighbours."""
    height, width = grid
    counts = np.zeros((height + 2, width + 2))
    points = np.zeros((height + 2, width + 2))
    counts[lit[:, 0] + 1, lit[:, 1] + 1] = touches
    points[lit[:, 0] + 1, lit[:, 1] + 1] = 1.0
    near_counts = sum(counts[1 + dy:height + 1 + dy, 1 + dx:width + 1 + dx]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1))
    near_points = sum(points[1 + dy:height + 1 + dy, 1 + dx:width + 1 + dx]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1))
    return near_counts[lit[:, 0], lit[:, 1]] / (near_points[lit[:, 0], lit[:, 1]] * photons)


def allocate(fractions: np.ndarray, photons: int) -> tuple[np.ndarray, np.ndarray]:
    """``(photons, direct)``: (n,) int64 photons per lit point, at least 1, and (n,) bool, the
    points scored whole, for reach ``fractions`` (n,): Neyman shares floored at :data:`FLOOR`
    of the largest, scaled to the expected cost of ``photons`` each."""
    direct = fractions > DIRECT_REACH
    cost = np.where(direct, 1.0, 1.0 + fractions)
    shares = np.where(direct, math.sqrt(0.5), np.sqrt(fractions / (1.0 + fractions)))
    if shares.max() <= 0.0:
        return np.full(len(fractions), photons, np.int64), direct
    shares = np.maximum(shares, FLOOR * shares.max())
    scale = photons * (1.0 + fractions).sum() / (shares * cost).sum()
    return np.maximum(1, np.rint(shares * scale)).astype(np.int64), direct
