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


def check_multiplexed_spacing(where: Path, frames, max_radius: float) -> None:
    """Raise DatasetError naming the first frame (of a :class:`.frame_table.FrameTable`) that
    lights two points at most ``2 * max_radius`` apart, and the two points."""
    limit = 2.0 * max_radius
    if all(close_pair(frames.lit[frames.starts[first]:frames.starts[stop]], limit,
                      np.repeat(np.arange(stop - first), frames.counts[first:stop]), first=False) is None
           for first, stop in _runs(frames.starts)):  # many frames at once: the usual, valid case
        return
    for index in np.flatnonzero(frames.counts > 1).tolist():  # name the first frame at fault
        frame = frames[index]
        pair = close_pair(frame.lit, limit)
        if pair is not None:
            p, q = frame.lit[min(pair)], frame.lit[max(pair)]  # in the manifest's order
            raise DatasetError(
                f"{where}: frames[{index}] ({frame.file}) lights {p.tolist()} and {q.tolist()} "
                f"{math.dist(p.tolist(), q.tolist()):.3g} apart; multiplexed points must be more than "
                f"2 * max_radius = {limit:g} apart"
            )


POINTS_AT_ONCE = 2**18
"""Lit points checked in one pass (here and by the manifest's other checks of its points): all
7.2 million of a long manifest at once made 400 MB of temporaries."""


def _runs(starts: np.ndarray) -> list[tuple[int, int]]:
    """``(first, stop)`` frame ranges of at most :data:`POINTS_AT_ONCE` points each (one frame at
    least), from the (F + 1,) starts of the frames' points."""
    runs, first = [], 0
    frames = len(starts) - 1
    while first < frames:
        stop = max(first + 1, int(np.searchsorted(starts, starts[first] + POINTS_AT_ONCE, side="right")) - 1)
        runs.append((first, min(stop, frames)))
        first = runs[-1][1]
    return runs


def close_pair(points: np.ndarray, limit: float, groups: np.ndarray | None = None,
               first: bool = True) -> tuple[int, int] | None:
    """Indices of two of the (n, 2) integer ``points`` at most ``limit`` apart, or None; with
    ``groups`` ((n,) int, e.g. each point's frame), only two points of one group count. With
    ``first``, the pair of the first point (in index order) that has a close one; without it, any
    pair, found in one forward sweep (whether there is one: 7.2 million points took 7.7 s of
    binary searches, nine a point).

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
    if first:
        found = _neighbour_pair(points, key, order, sorted_key, stride, limit * limit)
    else:
        found = _any_neighbour_pair(points, order, sorted_key, stride, limit * limit)
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


@numba.njit(cache=True, nogil=True)
def _any_neighbour_pair(points, order, sorted_key, stride, limit_sq):  # pragma: no cover - compiled
    """Some pair of points within ``limit_sq`` (squared) in one cell or two neighbouring ones;
    (-1, -1) when none. Each cell is compared with itself and its neighbours after it in key
    order (right; below left, below, below right), whose keys grow with its own, so that one
    pointer per neighbour moves forward through the sorted keys: linear time."""
    count = sorted_key.size
    deltas = np.array([1, stride - 1, stride, stride + 1], np.int64)
    pointers = np.zeros(4, np.int64)
    for at in range(count):
        i = order[at]
        key = sorted_key[at]
        later = at + 1
        while later < count and sorted_key[later] == key:
            other = order[later]
            dy = points[i, 0] - points[other, 0]
            dx = points[i, 1] - points[other, 1]
            if dy * dy + dx * dx <= limit_sq:
                return i, other
            later += 1
        for d in range(4):
            target = key + deltas[d]
            near = pointers[d]
            while near < count and sorted_key[near] < target:
                near += 1
            pointers[d] = near
            while near < count and sorted_key[near] == target:
                other = order[near]
                dy = points[i, 0] - points[other, 0]
                dx = points[i, 1] - points[other, 1]
                if dy * dy + dx * dx <= limit_sq:
                    return i, other
                near += 1
    return -1, -1
