"""Parallel capture: which points can be lit in the same frame.

docs/format/dataset.md attributes the light within ``max_radius`` of a lit point to it, so points lit together
must be more than ``2 * max_radius`` apart: a lattice of spacing ``floor(2 * max_radius) + 1``,
shifted over all its offsets, lights every grid point once in spacing^2 frames.
"""

from __future__ import annotations

import math

import numpy as np


def lattice_frames(height: int, width: int, max_radius: float) -> list[np.ndarray]:
    """Lit points per frame: a lattice of spacing floor(2 max_radius) + 1 (> 2 max_radius), or
    one point per frame when that is no more frames."""
    spacing = int(math.floor(2 * max_radius)) + 1
    if spacing * spacing >= height * width:
        return [np.array([[y, x]]) for y in range(height) for x in range(width)]
    frames = []
    for oy in range(min(spacing, height)):
        for ox in range(min(spacing, width)):
            ys, xs = np.mgrid[oy:height:spacing, ox:width:spacing]
            frames.append(np.stack([ys.ravel(), xs.ravel()], 1))
    return frames
