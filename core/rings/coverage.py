"""Ring coverage: how well the lit points of a dataset fill each ring (docs/format/dataset.md lets a dataset
light only some grid points, e.g. a lattice of every 4th point).

For a pixel ``p`` and a default ring of radius ``r`` (offsets ``r - w/2 <= |d| < r + w/2``), the
ring's *points* are its offsets landing inside the grid and its *members* those points that were
lit (not missing). E_r(p) is the mean of the members' responses; when few members remain, at
distances other than ``r``, a steep radial profile biases it (issue 19: T_4 38 % low on a slab lit
every 4th point). Coverage reports, per pixel and radius, the members, the ring points, the mean
member distance and the nearest member's distance from ``r``; :func:`coverage_warning` turns them
into one line when coverage is poor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..dataset.warm_up import warm_up_dataset
from .geometry import ring_geometry

NEAR_STEPS = 0.25
"""A ring is well placed when, on average over pixels, a member lies within this many grid steps of r."""
MIN_FRACTION = 0.25
"""A ring is well filled when, on average over pixels, at least this fraction of its points are members."""


@dataclass(frozen=True, eq=False)
class RingCoverage:
    """Coverage of the default rings of ``radii`` (grid steps) over an (H, W) grid.

    Attributes
    ----------
    radii
        (n,) float64 ring radii in grid steps; ``thickness`` the ring thickness w.
    members
        (n, H, W) int32: lit ring members behind E_r at each pixel (0 where p is unobserved).
    points
        (n, H, W) int32: ring offsets landing inside the grid at each pixel.
    mean_distance
        (n, H, W) float32: mean ``|d|`` of the members in grid steps; NaN without members.
    nearest_offset
        (n, H, W) float32: ``min | |d| - r |`` over the members in grid steps; NaN without members.
    """

    radii: np.ndarray
    thickness: float
    members: np.ndarray
    points: np.ndarray
    mean_distance: np.ndarray
    nearest_offset: np.ndarray

    def mean_nearest_offset(self) -> np.ndarray:
        """(n,) mean over pixels with members of :attr:`nearest_offset` (NaN when none has any)."""
        return _nan_mean(self.nearest_offset)

    def mean_member_fraction(self) -> np.ndarray:
        """(n,) mean over pixels with ring points of members / points (NaN when none has any)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            fraction = np.where(self.points > 0, self.members / np.maximum(self.points, 1), np.nan)
        return _nan_mean(fraction)

    def poor(self) -> np.ndarray:
        """(n,) bool: radii whose coverage is poor (see :func:`coverage_warning`)."""
        return self.means().poor()

    def means(self) -> "CoverageMeans":
        """The per-radius means that say whether coverage is poor."""
        return CoverageMeans(self.radii, self.mean_member_fraction(), self.mean_nearest_offset())

    def summary(self) -> dict:
        """Per-radius figures for ``stack.json``: JSON numbers (null for NaN)."""
        def listed(values):
            return [None if not np.isfinite(v) else round(float(v), 6) for v in values]

        return {"radii": [float(r) for r in self.radii],
                "mean_members": listed(_nan_mean(np.where(self.points > 0, self.members, np.nan))),
                "mean_points": listed(_nan_mean(np.where(self.points > 0, self.points, np.nan))),
                "mean_member_fraction": listed(self.mean_member_fraction()),
                "mean_nearest_offset": listed(self.mean_nearest_offset()),
                "poor": [bool(v) for v in self.poor()]}


@dataclass(frozen=True, eq=False)
class CoverageMeans:
    """What the explorer shows of a :class:`RingCoverage`: (n,) float64 means per radius of
    ``radii`` (grid steps) of the member fraction (over pixels with ring points) and of the nearest
    member's distance from r (over pixels with members, grid steps); NaN where no pixel has any."""

    radii: np.ndarray
    member_fraction: np.ndarray
    nearest_offset: np.ndarray

    def poor(self) -> np.ndarray:
        """(n,) bool: radii whose coverage is poor (see :func:`coverage_warning`)."""
        with np.errstate(invalid="ignore"):
            return (~(self.nearest_offset <= NEAR_STEPS)) | (~(self.member_fraction >= MIN_FRACTION))


def _nan_mean(values: np.ndarray) -> np.ndarray:
    """(n,) mean over the last two axes of the finite values of (n, H, W); NaN when none is."""
    finite = np.isfinite(values)
    count = finite.sum(axis=(1, 2))
    total = np.where(finite, values, 0.0).sum(axis=(1, 2), dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def ring_coverage(dataset: ImpulseDataset, radii, thickness: float = 1.0) -> RingCoverage:
    """Coverage of the default rings of ``radii`` (grid steps) in ``dataset``.

    Rings reaching beyond the dataset's ``max_radius`` count only the offsets it holds, as the
    stacks do. Memory: four (n, H, W) arrays and one band's validity flags. One compiled pass over
    each band's flags (at 800 x 800, R 24 and 23 radii: 7.7 s in numpy, every ring's flags
    gathered and reduced in turn).
    """
    radii = np.asarray(radii, np.float64).reshape(-1)
    height, width = dataset.grid_shape
    shape = (len(radii), height, width)
    members, points = np.zeros(shape, np.int32), np.zeros(shape, np.int32)
    mean_distance = np.full(shape, np.nan, np.float32)
    nearest = np.full(shape, np.nan, np.float32)
    index_of = {(int(dy), int(dx)): k for k, (dy, dx) in enumerate(dataset.offsets.tolist())}
    indices, ks, distances, starts = [], [], [], [0]
    for i, radius in enumerate(radii):
        offsets = [(int(dy), int(dx)) for dy, dx in ring_geometry(float(radius), thickness).offsets.tolist()
                   if (int(dy), int(dx)) in index_of]
        if offsets:
            indices.append(i)
            ks.extend(index_of[offset] for offset in offsets)
            distances.extend(np.hypot(*np.array(offsets, np.float64).T).astype(np.float32))
            starts.append(len(ks))
            points[i] = _points_inside(offsets, height, width)
    rings = (np.array(indices, np.int64), np.array(ks, np.int64), np.array(distances, np.float32),
             np.array(starts, np.int64), radii.astype(np.float32))
    for row0, row1 in dataset.bands():
        _band_coverage(dataset.validity_rows(row0, row1), *rings, members, mean_distance, nearest, row0)
    return RingCoverage(radii, float(thickness), members, points, mean_distance, nearest)


def warm_up_coverage() -> None:
    """Load the coverage's kernel (:func:`ring_coverage`) on a 2 x 1 dataset."""
    ring_coverage(warm_up_dataset(), [0.0, 1.0])


def _points_inside(offsets: list[tuple[int, int]], height: int, width: int) -> np.ndarray:
    """(H, W) int32: how many of ``offsets`` land inside the grid from each pixel. Each offset's
    pixels form a rectangle, added to a table of corner differences that two cumulative sums
    turn into the counts."""
    corners = np.zeros((height + 1, width + 1), np.int64)
    for dy, dx in offsets:
        y0, y1, x0, x1 = max(0, -dy), min(height, height - dy), max(0, -dx), min(width, width - dx)
        if y0 < y1 and x0 < x1:
            corners[y0, x0] += 1
            corners[y0, x1] -= 1
            corners[y1, x0] -= 1
            corners[y1, x1] += 1
    return corners.cumsum(0).cumsum(1)[:height, :width].astype(np.int32)


@numba.njit(parallel=True, cache=True, nogil=True)
def _band_coverage(validity, indices, ks, distances, starts, radii, members, mean_distance, nearest, row0):
    """Members, mean member distance and nearest member's distance from r of every ring
    (``ks[starts[j]:starts[j + 1]]`` the offsets of ring ``j``, radius index ``indices[j]``) at
    each point of a band of rows (``validity`` (rows, W, K) uint8, from grid row ``row0``)."""
    for y in numba.prange(validity.shape[0]):
        for x in range(validity.shape[1]):
            for ring in range(len(indices)):
                i = indices[ring]
                count, total, best = 0, 0.0, np.float32(np.inf)
                for j in range(starts[ring], starts[ring + 1]):
                    if validity[y, x, ks[j]]:
                        count += 1
                        total += distances[j]
                        best = min(best, abs(distances[j] - radii[i]))
                members[i, row0 + y, x] = count
                if count:
                    mean_distance[i, row0 + y, x] = total / count
                    nearest[i, row0 + y, x] = best


def coverage_warning(coverage: RingCoverage | CoverageMeans) -> str | None:
    """One line naming the radii whose coverage is poor, or None.

    Poor: on average over pixels no member lies within :data:`NEAR_STEPS` grid steps of ``r``,
    or fewer than :data:`MIN_FRACTION` of the ring's points are members (issue 19). Such ring
    means come from few points at other distances and are biased where the profile is steep.
    """
    means = coverage if isinstance(coverage, CoverageMeans) else coverage.means()
    poor = means.poor()
    if not poor.any():
        return None
    fraction, offset = means.member_fraction, means.nearest_offset
    shown = [f"r {r:g} ({'no member' if not np.isfinite(f) else f'{f:.0%} of ring points lit'}"
             + (f", nearest {o:.2f} from r" if np.isfinite(o) else "") + ")"
             for r, f, o in zip(means.radii[poor], fraction[poor], offset[poor])]
    more = f" and {len(shown) - 4} more" if len(shown) > 4 else ""
    return (f"poor ring coverage at {len(shown)} of {len(means.radii)} radii: {'; '.join(shown[:4])}{more}; "
            "sparse lit points bias these ring means (see --interpolate)")
