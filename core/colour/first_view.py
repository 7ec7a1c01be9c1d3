"""The view a dataset opens at: the radius, point and levels at which its structure stands out.

A transient image T_r of a nearly uniform material is nearly uniform too: the red-bead sample's
T_0 spans 0.115..0.117 (1 %), white at levels (0, robust max). Its structure is a small
relative variation, clearest at some radius and drowned by Monte Carlo or camera noise at
larger ones. :func:`first_view` picks that radius from the data alone:

- **contrast** of T_r: the robust range (1st to 99th percentile) of its luminance Y, box-
  smoothed over 3 x 3 points, divided by the median Y; over the points whose rings lie wholly on
  the grid (full member counts at r and r + dr), so that the grid's edge, where rings lose
  members, is not taken for structure;
- **noise** of T_r: the robust standard deviation (1.4826 x median absolute deviation) of Y
  minus its 3 x 3 box mean over the same points, divided by the median Y;
- the radius shown maximises contrast / max(noise, 1/256) (a contrast-to-noise ratio; below one
  step of an 8-bit display, noise is not seen), the first of equals;
- the point picked is, of those whose 5 x 5 box-smoothed Y lies furthest from the median there
  (within 90 % of the furthest), the one nearest their centroid;
- levels are each image's robust minimum to maximum (``"range"``), which spread that 1 % over
  the display. Where no radius shows structure (contrast under 2 %, or under 5 times the noise:
  a laterally uniform, layered material), the view stays at the first radius, the centre and
  the robust maximum, which shows the material's colour; its structure is in depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .display import DisplaySettings, shown_values

DISPLAY_STEP = 1.0 / 256
"""Relative noise below one step of an 8-bit display counts as this (it is not seen)."""
LEAST_CONTRAST = 0.02
"""Contrast below which a transient image is taken as uniform."""
LEAST_CONTRAST_TO_NOISE = 5.0
"""Contrast-to-noise ratio below which a transient image's variation is taken as noise (box-
smoothed white noise alone gives about 1.6)."""
CONTRAST_HALF_WIDTH = 1
PICK_HALF_WIDTH = 2
PICK_SHARE = 0.9


@dataclass(frozen=True, eq=False)
class FirstView:
    """Where a dataset's structure is seen (see the module notes).

    Attributes
    ----------
    radius_index
        Index into the stack's radii of the radius to show.
    pick
        (y, x) grid point on the structure (the grid's centre when ``structured`` is False).
    normalisation
        ``"range"`` when structured, else ``"per-image"``.
    contrast, noise
        (n,) relative contrast and noise of each T_r (0 where no point is fully covered).
    structured
        Whether some radius shows structure above the noise.
    """

    radius_index: int
    pick: tuple[int, int]
    normalisation: str
    contrast: np.ndarray
    noise: np.ndarray
    structured: bool

    @property
    def contrast_to_noise(self) -> np.ndarray:
        """(n,) contrast / max(noise, :data:`DISPLAY_STEP`)."""
        return self.contrast / np.maximum(self.noise, DISPLAY_STEP)


def first_view(images: np.ndarray, counts: np.ndarray, outer_counts: np.ndarray,
               colorspace: str = "sRGB") -> FirstView:
    """The first view of a transient stack.

    Parameters
    ----------
    images
        (n, H, W, 3) T_r, linear radiance in ``colorspace``; NaN where undefined.
    counts, outer_counts
        (n, H, W) ring members at r and at r + dr (the stack's ``counts`` and ``outer_counts``).

    Returns
    -------
    FirstView
    """
    n, height, width = images.shape[:3]
    contrast = np.zeros(n)
    noise = np.zeros(n)
    luminance = shown_values(images, DisplaySettings(channel="Y"), colorspace)  # (n, H, W) float32
    covered = [_fully_covered(luminance[index], counts[index], outer_counts[index]) for index in range(n)]
    for index in range(n):
        contrast[index], noise[index] = _contrast_and_noise(luminance[index], covered[index])
    ratio = contrast / np.maximum(noise, DISPLAY_STEP)
    best = int(np.argmax(ratio)) if n else 0
    structured = bool(n and contrast[best] >= LEAST_CONTRAST and ratio[best] >= LEAST_CONTRAST_TO_NOISE)
    if not structured:
        return FirstView(0, (height // 2, width // 2), "per-image", contrast, noise, False)
    return FirstView(best, _structure_point(luminance[best], covered[best]), "range", contrast, noise, True)


def _fully_covered(luminance: np.ndarray, counts: np.ndarray, outer_counts: np.ndarray) -> np.ndarray:
    """(H, W) bool: finite points whose rings at r and r + dr have as many members as any point
    has (rings wholly on the grid, no lit point missing); all finite points where none is."""
    finite = np.isfinite(luminance)
    full = finite & (counts == counts.max()) & (outer_counts == outer_counts.max())
    return full if full.any() else finite


def _contrast_and_noise(luminance: np.ndarray, covered: np.ndarray) -> tuple[float, float]:
    """Relative robust range of the 3 x 3 box mean and relative robust residual noise over the
    ``covered`` points; (0, 0) where none is covered or the median is not positive."""
    values = luminance[covered]
    if values.size == 0:
        return 0.0, 0.0
    median = float(np.median(values))
    if not median > 0:
        return 0.0, 0.0
    smooth = box_mean(luminance, covered, CONTRAST_HALF_WIDTH)[covered]
    low, high = np.percentile(smooth, [1.0, 99.0])
    residual = values - smooth
    spread = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    return float(high - low) / median, spread / median


def _structure_point(luminance: np.ndarray, covered: np.ndarray) -> tuple[int, int]:
    """Of the covered points whose 5 x 5 box mean lies furthest from the covered points' median
    (within :data:`PICK_SHARE` of the furthest), the one nearest their centroid: the middle of
    a flat-topped structure rather than wherever noise tops it."""
    smooth = box_mean(luminance, covered, PICK_HALF_WIDTH)
    deviation = np.where(covered, np.abs(smooth - np.median(luminance[covered])), -1.0)
    ys, xs = np.nonzero(deviation >= PICK_SHARE * deviation.max())
    nearest = int(np.argmin(np.hypot(ys - ys.mean(), xs - xs.mean())))
    return int(ys[nearest]), int(xs[nearest])


def box_mean(image: np.ndarray, mask: np.ndarray, half_width: int) -> np.ndarray:
    """(H, W) float64 mean of ``image`` over the ``mask`` points of each (2k+1) x (2k+1) window
    (k = ``half_width``), by summed-area tables; NaN where the window holds no mask point.

    Examples
    --------
    >>> box_mean(np.array([[1.0, 2.0, 9.0]]), np.array([[True, True, False]]), 1).tolist()
    [[1.5, 1.5, 2.0]]
    """
    values = np.where(mask, image, 0.0).astype(np.float64)
    weights = mask.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return _window_sums(values, half_width) / _window_sums(weights, half_width)


def _window_sums(array: np.ndarray, half_width: int) -> np.ndarray:
    """(H, W) sums of ``array`` over each (2k+1)-wide window, zero outside the grid."""
    side = 2 * half_width + 1
    table = np.pad(np.pad(array, half_width).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    return table[side:, side:] - table[:-side, side:] - table[side:, :-side] + table[:-side, :-side]
