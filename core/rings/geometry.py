"""Ring geometry: which lit points form the ring of radius r around a surface point.

The default ring (docs/format/dataset.md) of radius ``r`` and thickness ``w`` is the set of integer offsets
``d = [dy, dx]`` with ``r - w/2 <= |d| < r + w/2``, every member weighted 1. The anti-aliased ring
weights each offset by the exact area of its unit pixel square inside the annulus
``max(r - w/2, 0) <= |x| < r + w/2``, so its weights sum to the annulus area.
Distances are in grid steps.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class RingGeometry:
    """The members of one ring.

    Attributes
    ----------
    radius, thickness
        Ring radius and thickness in grid steps.
    antialias
        Whether weights are pixel-area coverages (else all 1).
    offsets
        (M, 2) int64 offsets ``[dy, dx]`` from the centre, sorted by angle.
    weights
        (M,) float64 weights in (0, 1].
    """

    radius: float
    thickness: float
    antialias: bool
    offsets: np.ndarray
    weights: np.ndarray

    @property
    def outer_radius(self) -> float:
        """Largest centre distance of any member, in grid steps (0 for an empty ring)."""
        if len(self.offsets) == 0:
            return 0.0
        return float(np.sqrt((self.offsets.astype(np.float64) ** 2).sum(1)).max())

    def around(self, center: tuple[int, int], grid_shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Members around ``center = (y, x)`` that lie inside a grid of ``grid_shape = (H, W)``.

        Returns ``(positions, weights)``: (m, 2) int64 grid positions ``[y, x]`` and (m,) weights.
        """
        positions = self.offsets + np.asarray(center, np.int64)
        inside = (
            (positions[:, 0] >= 0) & (positions[:, 0] < grid_shape[0])
            & (positions[:, 1] >= 0) & (positions[:, 1] < grid_shape[1])
        )
        return positions[inside], self.weights[inside]


def ring_geometry(radius: float, thickness: float = 1.0, antialias: bool = False) -> RingGeometry:
    """Members and weights of the ring of ``radius`` and ``thickness`` (grid steps).

    Examples
    --------
    >>> ring_geometry(1.0).offsets.tolist()  # 1 - 1/2 <= |d| < 1 + 1/2: the 8 neighbours
    [[-1, -1], [-1, 0], [-1, 1], [0, 1], [1, 1], [1, 0], [1, -1], [0, -1]]
    >>> round(float(ring_geometry(3.0, antialias=True).weights.sum()), 6)  # area 2 pi r w
    18.849556
    >>> ring_geometry(0.0).offsets.tolist()
    [[0, 0]]
    """
    if not np.isfinite(radius) or radius < 0:
        raise ValueError(f"ring radius must be finite and >= 0, got {radius}")
    if not np.isfinite(thickness) or thickness <= 0:
        raise ValueError(f"ring thickness must be finite and > 0, got {thickness}")
    return _ring_geometry_cached(float(radius), float(thickness), bool(antialias))


@functools.lru_cache(maxsize=1024)
def _ring_geometry_cached(radius: float, thickness: float, antialias: bool) -> RingGeometry:
    inner = max(radius - thickness / 2.0, 0.0)
    outer = radius + thickness / 2.0
    reach = int(np.ceil(outer + 1.0))
    dy, dx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    dy, dx = dy.ravel(), dx.ravel()
    if antialias:
        weights = annulus_pixel_area(dy, dx, inner, outer)
        keep = weights > 1e-12
    else:
        distance = np.sqrt(dy * dy + dx * dx)
        keep = (distance >= radius - thickness / 2.0) & (distance < outer)
        weights = np.ones(dy.shape)
    dy, dx, weights = dy[keep], dx[keep], weights[keep]
    order = np.lexsort((np.hypot(dy, dx), np.arctan2(dy, dx)))
    offsets = np.stack([dy[order], dx[order]], axis=1).astype(np.int64)
    result = RingGeometry(radius, thickness, antialias, offsets, weights[order].astype(np.float64))
    result.offsets.flags.writeable = False
    result.weights.flags.writeable = False
    return result


def ring_outer_radius(radius: float, thickness: float = 1.0) -> float:
    """:attr:`RingGeometry.outer_radius` of :func:`ring_geometry`'s default ring (not
    anti-aliased), without building it: work and memory grow with the radius, not its square (the
    ring of radius 4000 took 2.3 GB before a stack was refused as beyond the dataset's
    max_radius). An anti-aliased ring holds every member of the default ring, so this is a lower
    bound of its outer radius.

    The ring is symmetric under sign changes and the swap of ``dy`` and ``dx``, so its farthest
    member lies in the octant ``0 <= dy <= dx``, where the circle's slope is at least 45 degrees:
    in each row the farthest member is one of the few columns where the outer circle crosses.
    """
    if not np.isfinite(radius) or radius < 0:
        raise ValueError(f"ring radius must be finite and >= 0, got {radius}")
    if not np.isfinite(thickness) or thickness <= 0:
        raise ValueError(f"ring thickness must be finite and > 0, got {thickness}")
    outer = radius + thickness / 2.0
    rows = np.arange(0, int(np.ceil(outer / np.sqrt(2.0))) + 3)
    crossing = np.floor(np.sqrt(np.maximum(outer * outer - rows * rows, 0.0))).astype(np.int64)
    dy = np.repeat(rows, 4)
    dx = (crossing[:, None] + np.arange(1, -3, -1)[None]).ravel()
    dy, dx = dy[dx >= dy], dx[dx >= dy]
    # The same test as ring_geometry's, on the same float64 values.
    distance = np.sqrt(dy * dy + dx * dx)
    member = (distance >= radius - thickness / 2.0) & (distance < outer)
    return float(distance[member].max()) if member.any() else 0.0


def annulus_pixel_area(dy: np.ndarray, dx: np.ndarray, inner: float, outer: float) -> np.ndarray:
    """Exact area of each unit pixel square centred at ``(dy, dx)`` inside an annulus.

    The annulus is ``inner <= |x| <= outer`` centred at the origin (boundaries have no area).
    Returns float64 of the broadcast shape of ``dy`` and ``dx``.
    """
    dy = np.asarray(dy, np.float64)
    dx = np.asarray(dx, np.float64)
    return _square_disc_area(dy, dx, outer) - _square_disc_area(dy, dx, inner)


def _square_disc_area(cy: np.ndarray, cx: np.ndarray, rho: float) -> np.ndarray:
    """Area of the unit square centred at (cy, cx) inside the disc of radius rho at the origin."""
    if rho <= 0:
        return np.zeros(np.broadcast(cy, cx).shape)
    x0, x1, y0, y1 = cx - 0.5, cx + 0.5, cy - 0.5, cy + 0.5
    # Inclusion-exclusion over the rectangle's corners with a signed quadrant area.
    return (
        _signed_quadrant_area(x1, y1, rho) - _signed_quadrant_area(x0, y1, rho)
        - _signed_quadrant_area(x1, y0, rho) + _signed_quadrant_area(x0, y0, rho)
    )


def _signed_quadrant_area(x: np.ndarray, y: np.ndarray, rho: float) -> np.ndarray:
    """sign(x) sign(y) * area of {0 <= u <= |x|, 0 <= v <= |y|} inside the disc of radius rho."""
    a, b = np.abs(x), np.abs(y)
    # Integrate min(b, sqrt(rho^2 - u^2)) for u in [0, min(a, rho)] with the antiderivative
    # F(u) = (u sqrt(rho^2 - u^2) + rho^2 asin(u / rho)) / 2 of the circle's upper half.
    a_cap = np.minimum(a, rho)
    u_cross = np.sqrt(np.maximum(rho * rho - b * b, 0.0))  # where the circle meets v = b
    flat = np.minimum(a_cap, u_cross)
    area = b * flat + _circle_antiderivative(a_cap, rho) - _circle_antiderivative(flat, rho)
    return np.sign(x) * np.sign(y) * area


def _circle_antiderivative(u: np.ndarray, rho: float) -> np.ndarray:
    u = np.clip(u, -rho, rho)
    return 0.5 * (u * np.sqrt(np.maximum(rho * rho - u * u, 0.0)) + rho * rho * np.arcsin(u / rho))
