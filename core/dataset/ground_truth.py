"""Comparing transient images with a synthetic dataset's path-length ground truth.

A simulated dataset carries images of the light whose path length inside the surface lies in
``[min, max)`` grid steps (docs/format/dataset.md ``ground_truth.path_length_images``). A transient image T_r
bounds path length to about [r, r+dr), so each T_r is compared with the bin that best matches that
interval, by zero-mean normalised cross-correlation (NCC), which ignores the two images' scales.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import DatasetError
from .exr import read_exr_rgb
from .manifest import Manifest

MAX_GROUND_TRUTH_BYTES = 4 * 2**30
"""Largest stack of path-length images read (checked by arithmetic before allocating)."""


@dataclass(frozen=True, eq=False)
class PathLengthImages:
    """Ground-truth path-length images.

    Attributes
    ----------
    bounds
        (m, 2) float64 ``[min, max)`` path length of each bin in grid steps.
    images
        (m, H, W, 3) float32 linear radiance under uniform illumination.
    """

    bounds: np.ndarray
    images: np.ndarray

    def nearest_bin(self, radius: float, step: float) -> int:
        """Index of the bin overlapping ``[radius, radius + step)`` most; ties and no overlap
        go to the bin whose centre is nearest the interval's centre."""
        low = np.maximum(self.bounds[:, 0], radius)
        high = np.minimum(self.bounds[:, 1], radius + step)
        overlap = np.maximum(high - low, 0.0)
        distance = np.abs(self.bounds.mean(axis=1) - (radius + step / 2))
        return int(np.lexsort((distance, -overlap))[0])


def read_path_length_images(
    manifest: Manifest, progress: Callable[[float], None] | None = None, allow_outside: bool = False
) -> PathLengthImages | None:
    """The dataset's path-length images, or None when it has none.

    Raises DatasetError naming the file when an image is unreadable or of the wrong size.
    """
    entries = manifest.ground_truth.path_length_images if manifest.ground_truth else ()
    if not entries:
        return None
    needed = len(entries) * manifest.height * manifest.width * 3 * 4  # Python ints: no overflow
    if needed > MAX_GROUND_TRUTH_BYTES:
        raise DatasetError(f"{manifest.path}: {len(entries)} path-length images of {manifest.height} x "
                           f"{manifest.width} need {needed / 2**30:.1f} GiB, over the "
                           f"{MAX_GROUND_TRUTH_BYTES / 2**30:.0f} GiB ringlight reads")
    images = np.empty((len(entries), manifest.height, manifest.width, 3), np.float32)
    for index, entry in enumerate(entries):
        path = manifest.file_path(entry.file, allow_outside)
        images[index] = read_exr_rgb(path, (manifest.height, manifest.width), "ground-truth image", "the grid")
        if progress is not None:
            progress((index + 1) / len(entries))
    bounds = np.array([(entry.min, entry.max) for entry in entries], np.float64)
    return PathLengthImages(bounds, images)


def normalised_cross_correlation(first: np.ndarray, second: np.ndarray) -> float:
    """Zero-mean NCC of two same-shape arrays over the entries finite in both, in [-1, 1].

    NaN when fewer than two entries are finite or either is constant there.
    """
    first = np.asarray(first, np.float64).ravel()
    second = np.asarray(second, np.float64).ravel()
    both = np.isfinite(first) & np.isfinite(second)
    if both.sum() < 2:
        return float("nan")
    a = first[both] - first[both].mean()
    b = second[both] - second[both].mean()
    norm = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / norm) if norm > 0 else float("nan")


def scaled_difference(transient: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, float]:
    """``transient - a * truth`` and ``a``, for two same-shape arrays (H, W, 3), with ``a`` the
    least-squares scale of the truth onto the transient over the entries finite in both (the two
    are in different units: NCC ignores that, a difference must match it first).

    The difference is float32, NaN where either is not finite; ``a`` is NaN (and the difference
    all NaN) when the truth is zero or not finite everywhere.
    """
    first = np.asarray(transient, np.float64)
    second = np.asarray(truth, np.float64)
    both = np.isfinite(first) & np.isfinite(second)
    energy = float((second[both] ** 2).sum())
    scale = float((first[both] * second[both]).sum() / energy) if energy > 0 else float("nan")
    difference = np.where(both, first - scale * second, np.nan)
    return difference.astype(np.float32), scale


def stack_correlations(radii: np.ndarray, step: float, images: np.ndarray,
                       truth: PathLengthImages) -> np.ndarray:
    """(n,) NCC of each transient image ``images[i]`` (n, H, W, 3) with its nearest bin."""
    return np.array([
        normalised_cross_correlation(images[i], truth.images[truth.nearest_bin(float(r), step)])
        for i, r in enumerate(radii)
    ])
