"""An optional estimator of ring light images for sparsely lit datasets: each pixel's responses
interpolated in exact distance, instead of the mean of the few ring members that were lit.

For a pixel ``p``, the responses ``I_q(p)`` of its lit points ``q`` are grouped by exact distance
``|q - p|`` (mean per distance): a sampled radial profile ``f_p``. The estimate of ``E_r(p)`` is
the mean of ``f_p(|d|)`` over the dense ring's offsets ``d`` that land in the grid, ``f_p`` taken
between its two nearest samples, log-linearly when both are positive (diffuse profiles fall off
about exponentially), else linearly; before the nearest or after the farthest sample, the two
nearest samples are extrapolated up to ``max_gap`` grid steps, beyond which the estimate is
undefined (NaN). On a
densely lit grid every ring offset is a sample and the estimate is the ring mean of docs/format/dataset.md.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from .geometry import ring_geometry
from .stacks import Stack

DEFAULT_MAX_GAP = 2.0
"""Farthest (grid steps) the end samples of a profile are extended beyond it."""


@numba.njit(cache=True, nogil=True)
def _profile_value(distances, values, count, target, channel, max_gap):  # pragma: no cover - compiled
    """f(target) from ``count`` samples (increasing ``distances``); NaN beyond ``max_gap``.

    Between samples: the two around ``target``; before the first or after the last: the two
    nearest it, extrapolated (one sample: its value)."""
    if target < distances[0] - max_gap or target > distances[count - 1] + max_gap:
        return np.nan
    if count == 1:
        return values[0, channel]
    low, high = 0, count - 1
    if target <= distances[0]:
        high = 1
    elif target >= distances[count - 1]:
        low = count - 2
    else:
        while high - low > 1:
            middle = (low + high) // 2
            if distances[middle] <= target:
                low = middle
            else:
                high = middle
    t = (target - distances[low]) / (distances[high] - distances[low])
    a, b = values[low, channel], values[high, channel]
    if a > 0 and b > 0:
        return math.exp((1 - t) * math.log(a) + t * math.log(b))
    return (1 - t) * a + t * b


@numba.njit(parallel=True, cache=True, nogil=True)
def _interpolated_rings(responses, validity, dy, dx, distance, ring_start, ring_offsets, max_gap, out,
                        row0):  # pragma: no cover - compiled
    """``out[i, row0 + y]`` of the whole grid's (n, H, W, 3) ``out`` for the band of grid rows
    ``row0 + y`` (``responses`` and ``validity`` hold the band's rows): the whole array, so that the
    kernel is compiled for one layout (a band's slice was contiguous when one band covered the grid
    and strided otherwise: two compiles of 4-5 s)."""
    height = out.shape[1]
    rows, width, offsets = validity.shape
    for y in numba.prange(rows):
        samples = np.empty(offsets, np.float64)
        values = np.empty((offsets, 3), np.float64)
        for x in range(width):
            # Samples of the profile: lit offsets grouped by equal distance (offsets are sorted by it).
            count = 0
            members = 0
            for k in range(offsets):
                if validity[y, x, k] == 0:
                    continue
                if count > 0 and abs(distance[k] - samples[count - 1]) < 1e-9:
                    members += 1
                    for c in range(3):
                        values[count - 1, c] += (responses[y, x, k, c] - values[count - 1, c]) / members
                else:
                    samples[count] = distance[k]
                    members = 1
                    for c in range(3):
                        values[count, c] = responses[y, x, k, c]
                    count += 1
            for i in range(ring_start.size - 1):
                total = np.zeros(3)
                used = 0
                for j in range(ring_start[i], ring_start[i + 1]):
                    k = ring_offsets[j]
                    qy, qx = row0 + y + dy[k], x + dx[k]
                    if qy < 0 or qy >= height or qx < 0 or qx >= width:
                        continue
                    used += 1
                    for c in range(3):
                        total[c] += _profile_value(samples, values, count, distance[k], c, max_gap) if count else np.nan
                for c in range(3):
                    out[i, row0 + y, x, c] = total[c] / used if used else np.nan


def interpolated_ring_stack(dataset: ImpulseDataset, radii, thickness: float = 1.0,
                            max_gap: float = DEFAULT_MAX_GAP) -> Stack:
    """Ring light images estimated by interpolating each pixel's responses in distance.

    Parameters
    ----------
    dataset
        An opened dataset (its responses reach ``max_radius``).
    radii
        Ring radii in grid steps.
    thickness
        Ring thickness w in grid steps: the dense ring whose mean is estimated.
    max_gap
        How far (grid steps) the profile's end samples may be extended.

    Returns
    -------
    A ring :class:`Stack`: (len(radii), H, W, 3) float32 images, NaN where undefined (no sample,
    or the ring beyond ``max_gap`` of every sample, or unobserved ``p``); ``counts`` holds the
    ring points in the grid (the dense ring's size), not lit members.
    """
    radii = np.asarray(radii, np.float64).reshape(-1)
    index_of = {(int(dy), int(dx)): k for k, (dy, dx) in enumerate(dataset.offsets.tolist())}
    rings = [[index_of[(int(dy), int(dx))] for dy, dx in ring_geometry(float(r), thickness).offsets.tolist()
              if (int(dy), int(dx)) in index_of] for r in radii]
    ring_start = np.concatenate([[0], np.cumsum([len(ring) for ring in rings])]).astype(np.int64)
    ring_offsets = np.array([k for ring in rings for k in ring], np.int64)
    offsets = dataset.offsets
    distance = np.hypot(offsets[:, 0], offsets[:, 1]).astype(np.float64)
    height, width = dataset.grid_shape
    images = np.empty((len(radii), height, width, 3), np.float32)
    for row0, row1 in dataset.bands():
        _interpolated_rings(dataset.rows(row0, row1), dataset.validity_rows(row0, row1),
                            np.ascontiguousarray(offsets[:, 0]), np.ascontiguousarray(offsets[:, 1]), distance,
                            ring_start, ring_offsets, float(max_gap), images, row0)
    images[:, ~dataset.observed] = np.nan
    yy, xx = np.mgrid[:height, :width]
    counts = np.stack([sum(((yy + offsets[k, 0] >= 0) & (yy + offsets[k, 0] < height) & (xx + offsets[k, 1] >= 0)
                            & (xx + offsets[k, 1] < width)).astype(np.int32) for k in ring) if ring
                       else np.zeros((height, width), np.int32) for ring in rings]).astype(np.int32)
    return Stack("ring", radii, float(thickness), False, dataset.colorspace, images, counts)


def interpolated_stack(dataset: ImpulseDataset, radii, kind: str = "ring", step: float = 1.0,
                       thickness: float = 1.0, max_gap: float = DEFAULT_MAX_GAP) -> Stack:
    """A ring stack (``kind`` "ring") or transient stack (T_r = E_r - E_{r+step}) from
    :func:`interpolated_ring_stack`'s estimates; (len(radii), H, W, 3) float32 images."""
    radii = np.asarray(radii, np.float64).reshape(-1)
    if kind == "ring":
        return interpolated_ring_stack(dataset, radii, thickness, max_gap)
    rings = interpolated_ring_stack(dataset, np.concatenate([radii, radii + step]), thickness, max_gap)
    n = len(radii)
    return Stack("transient", radii, float(thickness), False, dataset.colorspace,
                 rings.images[:n] - rings.images[n:], rings.counts[:n], rings.counts[n:], float(step))
