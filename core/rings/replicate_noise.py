"""Standard errors of ring light and transient images from a dataset's replicates: each replicate's
E_r and T_r computed on its own, their spread over the replicates (:mod:`..dataset.replicates`).

With ``K`` replicates, ``SE(Q) = std_k(Q_k) / sqrt(K)`` (ddof 1) for Q = E_r(p), T_r(p) and their
luminance. Unlike the spread of a ring's members (:mod:`.noise`), this holds noise shared by lit
points (a simulated kernel common to every point, a projector's flicker) and needs no homogeneous
surface; and T_r's error is its own, not bounded from E_r's and E_{r+dr}'s (which covary, strongly
where the lit points share a kernel). It is a spread over ``K`` values, so itself uncertain by
about ``1 / sqrt(2 (K - 1))`` of its value (25 % at K = 8).

Each replicate is opened in memory (its responses must fit the memory budget).
"""

from __future__ import annotations

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback, open_dataset
from ..dataset.replicates import replicate_manifests
from .stacks import ring_stack


def replicate_spread(dataset: ImpulseDataset, unique: np.ndarray, inner: np.ndarray, outer: np.ndarray,
                     thickness: float, antialias: bool, luma: np.ndarray,
                     progress: ProgressCallback | None = None) -> tuple[np.ndarray, ...]:
    """Standard errors over ``dataset``'s replicates of E_r at ``unique[inner]`` and of
    T_r = E(unique[inner]) - E(unique[outer]) (radii in grid steps).

    Returns ``(ring, transient)`` (n, H, W, 3) and ``(ring_luminance, transient_luminance)``
    (n, H, W), float32, NaN where some replicate's ring has no member; ``progress`` gets the
    fraction of replicates done and may raise ``Cancelled``."""
    manifests = replicate_manifests(dataset.manifest)
    count = len(manifests)
    sums = None
    for index, manifest in enumerate(manifests):
        replicate = open_dataset(manifest, radius=dataset.max_radius, use_cache=False)
        images = ring_stack(replicate, unique, thickness, antialias).images.astype(np.float64)
        ring, transient = images[inner], images[inner] - images[outer]
        values = (ring, transient, ring @ luma, transient @ luma)
        if sums is None:
            sums = [np.zeros_like(value) for value in values], [np.zeros_like(value) for value in values]
        for total, square, value in zip(*sums, values):
            total += value
            square += value * value
        if progress is not None:
            progress((index + 1) / count)
    errors = []
    for total, square in zip(*sums):
        mean = total / count
        variance = np.maximum(square / count - mean * mean, 0.0) * count / (count - 1)
        errors.append(np.sqrt(variance / count).astype(np.float32))
    return tuple(errors)
