"""Regions of the grid: all pixels, a rectangle, a polygon or a mask, as (H, W) bool masks.

Coordinates follow the explorer's view: pixel ``(y, x)`` covers ``[x, x+1) x [y, y+1)``, so
its centre is ``(y + 0.5, x + 0.5)``; a polygon contains the pixels whose centres it contains.
"""

from __future__ import annotations

import numpy as np

from ..errors import RinglightError


class RegionError(RinglightError):
    """A region that selects nothing usable, or is malformed."""


def full_region(grid_shape: tuple[int, int]) -> np.ndarray:
    """Every pixel of an (H, W) grid."""
    return np.ones(grid_shape, bool)


def rectangle_region(grid_shape: tuple[int, int], y0: int, x0: int, y1: int, x1: int) -> np.ndarray:
    """Pixels with ``y0 <= y < y1`` and ``x0 <= x < x1``; raises RegionError when that is empty
    or outside the grid."""
    height, width = grid_shape
    if not (0 <= y0 < y1 <= height and 0 <= x0 < x1 <= width):
        raise RegionError(
            f"region rows {y0}..{y1} and columns {x0}..{x1} (end exclusive) must be non-empty and "
            f"inside the {height} x {width} grid"
        )
    mask = np.zeros(grid_shape, bool)
    mask[y0:y1, x0:x1] = True
    return mask


def polygon_region(grid_shape: tuple[int, int], vertices) -> np.ndarray:
    """Pixels whose centres lie inside the polygon of (m, 2) ``vertices`` ``[y, x]`` (view
    coordinates, m >= 3), by the even-odd crossing rule over all centres at once."""
    vertices = np.asarray(vertices, np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3 or not np.isfinite(vertices).all():
        raise RegionError(f"a polygon region needs at least 3 finite [y, x] vertices, got {vertices.shape}")
    cy, cx = (np.mgrid[:grid_shape[0], :grid_shape[1]] + 0.5)[:, :, :, None]
    y0, x0 = vertices[:, 0], vertices[:, 1]
    y1, x1 = np.roll(y0, -1), np.roll(x0, -1)
    # An edge is crossed by the ray from a centre towards +x when it straddles the centre's row
    # (half-open in y, so a vertex on the row counts once) and meets that row right of the centre.
    straddles = (y0 <= cy) != (y1 <= cy)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing_x = x0 + (cy - y0) * (x1 - x0) / (y1 - y0)
    crossings = (straddles & (crossing_x > cx)).sum(axis=-1)
    return crossings % 2 == 1


def parse_rectangle(text: str) -> tuple[int, int, int, int]:
    """``"Y0,X0,Y1,X1"`` -> integers (end exclusive)."""
    try:
        values = tuple(int(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise RegionError(f"region {text!r} must be Y0,X0,Y1,X1 (integers, end exclusive), e.g. 4,4,20,20")
    return values


def region_statistics(image: np.ndarray, region: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """Count, mean and standard deviation of an (H, W, 3) image over an (H, W) bool region.

    Pixels with a NaN channel (undefined) are left out. Returns ``(count, mean (3,), std (3,))``;
    mean and std are NaN when no pixel counts.
    """
    values = np.asarray(image, np.float64)[np.asarray(region, bool)]
    values = values[np.isfinite(values).all(axis=1)]
    if not len(values):
        return 0, np.full(3, np.nan), np.full(3, np.nan)
    return len(values), values.mean(axis=0), values.std(axis=0)
