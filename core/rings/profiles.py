"""E(r) and T(r) at one surface point, computed straight from the response model.

A profile is what the explorer plots for a picked pixel: the ring light value E_r(p) for every
radius of a stack, the outer ring E_{r+dr}(p), and their difference T_r(p) (paper Eq. 8). It uses
the same rings and weights as :mod:`ringlight.core.stacks`, so it equals the stack at ``p``, but
costs one small matrix product instead of a whole stack.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from .stacks import Stack, ring_weight_matrix


@dataclass(frozen=True, eq=False)
class ProfileRings:
    """Weight matrices of a stack's rings, made once per stack and reused for every point.

    Attributes
    ----------
    radii
        (n,) ring radii in grid steps.
    step
        dr in grid steps.
    inner, outer
        (n, K) float64 weights of the rings of radius r and r + dr over the offset axis.
    """

    radii: np.ndarray
    step: float
    inner: np.ndarray
    outer: np.ndarray


@dataclass(frozen=True, eq=False)
class PixelProfile:
    """Profiles at one point ``(y, x)``; NaN where a ring has no member.

    Attributes
    ----------
    radii
        (n,) ring radii in grid steps.
    ring, outer_ring, transient
        (n, 3) float64 linear radiance: E_r, E_{r+dr} and T_r = E_r - E_{r+dr}.
    counts, outer_counts
        (n,) int: ring members behind E_r and E_{r+dr}.
    """

    point: tuple[int, int]
    radii: np.ndarray
    step: float
    ring: np.ndarray
    outer_ring: np.ndarray
    transient: np.ndarray
    counts: np.ndarray
    outer_counts: np.ndarray


def profile_rings(dataset: ImpulseDataset, radii, step: float, thickness: float = 1.0,
                  antialias: bool = False) -> ProfileRings:
    """Weight matrices for :func:`pixel_profile` (raises StackError like the stacks do)."""
    radii = np.asarray(radii, np.float64)
    inner = ring_weight_matrix(dataset, radii, thickness, antialias)
    outer = ring_weight_matrix(dataset, radii + step, thickness, antialias)
    return ProfileRings(radii, float(step), inner, outer)


def pixel_profile(dataset: ImpulseDataset, rings: ProfileRings, point: tuple[int, int]) -> PixelProfile:
    """E(r), E(r + dr) and T(r) at grid point ``point = (y, x)`` for every radius of ``rings``."""
    y, x = int(point[0]), int(point[1])
    validity = dataset.validity_rows(y, y + 1)[0, x].astype(np.float64)
    responses = np.asarray(dataset.point(y, x), np.float64)
    ring, counts = _weighted_means(rings.inner * validity, responses)
    outer_ring, outer_counts = _weighted_means(rings.outer * validity, responses)
    return PixelProfile(
        (y, x), rings.radii, rings.step, ring, outer_ring, ring - outer_ring, counts, outer_counts
    )


def stack_profile(ring: Stack, transient: Stack, point: tuple[int, int]) -> PixelProfile:
    """The profile at ``point`` read from computed stacks of the same radii (no response read:
    what the explorer shows for a dataset read from its store, whose click must not wait on I/O).

    Equal to :func:`pixel_profile` up to the stacks' float32 rounding: E_{r+dr} is E_r - T_r."""
    y, x = int(point[0]), int(point[1])
    values = ring.images[:, y, x].astype(np.float64)
    difference = transient.images[:, y, x].astype(np.float64)
    return PixelProfile((y, x), ring.radii, float(transient.step), values, values - difference, difference,
                        ring.counts[:, y, x].astype(int), transient.outer_counts[:, y, x].astype(int))


def _weighted_means(weights: np.ndarray, responses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    totals = weights.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = (weights @ responses) / totals[:, None]
    means[totals == 0] = np.nan
    return means, np.count_nonzero(weights, axis=1)


def profile_csv(profile: PixelProfile) -> str:
    """The profile as CSV text: one row per radius, radiance in full float precision."""
    buffer = io.StringIO()
    y, x = profile.point
    buffer.write(f"# ringlight profile at y={y} x={x}; dr={profile.step:g}; radii in grid steps\n")
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow([
        "radius", "E_R", "E_G", "E_B", "E_count", "E_outer_R", "E_outer_G", "E_outer_B",
        "E_outer_count", "T_R", "T_G", "T_B",
    ])
    for index, radius in enumerate(profile.radii):
        writer.writerow([
            repr(float(radius)), *map(repr, profile.ring[index].tolist()), int(profile.counts[index]),
            *map(repr, profile.outer_ring[index].tolist()), int(profile.outer_counts[index]),
            *map(repr, profile.transient[index].tolist()),
        ])
    return buffer.getvalue()
