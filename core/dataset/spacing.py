"""The spacing rule of multiplexed frames (docs/format/dataset.md): points lit in one frame are more than
``2 * max_radius`` apart, so that no grid point sees two of them within ``max_radius``.

Checked for every frame of a manifest at once, in linear time, compiled: a paper-scale capture
has 2401 frames of 267 points each.
"""

from __future__ import annotations

import math
from pathlib import Path

import numba
import numpy as np

from ..errors import DatasetError


def check_multiplexed_spacing(where: Path, frames: tuple, max_radius: float) -> None:
    """Raise DatasetError naming the first frame (of ``FrameEntry``) that lights two points at most
    ``2 * max_radius`` apart, and the two points."""
    limit = 2.0 * max_radius
    points = np.concatenate([frame.lit for frame in frames])
    groups = np.repeat(np.arange(len(frames)), [len(frame.lit) for frame in frames])
    if close_pair(points, limit, groups) is None:  # every frame at once: the usual, valid case
        return
    for index, frame in enumerate(frames):  # name the first frame at fault
        pair = close_pair(frame.lit, limit)
        if pair is not None:
            p, q = frame.lit[min(pair)], frame.lit[max(pair)]  # in the manifest's order
            raise DatasetError(
                f"{where}: frames[{index}] ({frame.file}) lights {p.tolist()} and {q.tolist()} "
                f"{math.dist(p.tolist(), q.tolist()):.3g} apart; multiplexed points must be more than "
                f"2 * max_radius = {limit:g} apart"
            )


def close_pair(points: np.ndarray, limit: float, groups: np.ndarray | None = None) -> tuple[int, int] | None:
    """Indices of two of the (n, 2) integer ``points`` at most ``limit`` apart, or None; with
    ``groups`` ((n,) int, e.g. each point's frame), only two points of one group count.

    Linear time: points are binned into square cells of side ``floor(limit) + 1``, so a close
    pair lies in one cell or two neighbouring ones, and a cell of points pairwise farther than
    ``limit`` apart holds at most 4 of them (a square of side ``a <= limit`` holds at most 4
    points at mutual distances over ``a``); a fuller cell is checked by brute force.
    """
    count = len(points)
    if count < 2:
        return None
    side = math.floor(limit) + 1
    cells = points // side + 1  # >= 1, so that neighbour -1 stays non-negative
    stride = int(cells[:, 1].max()) + 2
    key = cells[:, 0] * stride + cells[:, 1]
    if groups is not None:  # each group's cells in a block of its own: neighbours never cross
        key = key + groups.astype(np.int64) * ((int(cells[:, 0].max()) + 2) * stride)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_key[1:] != sorted_key[:-1]]))
    sizes = np.diff(np.append(starts, count))
    if sizes.max() > 4:
        members = order[starts[np.argmax(sizes)]:][:5]
        distances = np.hypot(*(points[members][:, None] - points[members][None]).transpose(2, 0, 1))
        distances[np.diag_indices(len(members))] = np.inf
        a, b = np.unravel_index(np.argmin(distances), distances.shape)
        return int(members[a]), int(members[b])
    found = _neighbour_pair(points, key, order, sorted_key, stride, limit * limit)
    return None if found[0] < 0 else (int(found[0]), int(found[1]))


@numba.njit(cache=True, nogil=True)
def _neighbour_pair(points, key, order, sorted_key, stride, limit_sq):  # pragma: no cover - compiled
    """The first point (in index order) with another within ``limit_sq`` (squared) in its cell or
    a neighbouring one, and that other point; (-1, -1) when none. Cells hold at most 4 points."""
    count = points.shape[0]
    for i in range(count):
        for row in range(-1, 2):
            for column in range(-1, 2):
                target = key[i] + row * stride + column
                at = np.searchsorted(sorted_key, target)
                while at < count and sorted_key[at] == target:
                    other = order[at]
                    if other != i:
                        dy = points[i, 0] - points[other, 0]
                        dx = points[i, 1] - points[other, 1]
                        if dy * dy + dx * dx <= limit_sq:
                            return i, other
                    at += 1
    return -1, -1
