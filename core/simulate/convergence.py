"""How converged a simulation is: ring light and transient images straight from a transport's
windows, and the relative noise of two independent halves.

The noise figure (issue 12) of two independent estimates ``a`` and ``b`` of the transient
images ``T_r = E_r - E_{r+1}`` (docs/format/dataset.md's default rings, thickness 1, unit weights) is

    RMS(T_a - T_b) / sqrt(2) / RMS((T_a + T_b) / 2)

over the grid and the three channels: the relative noise of one estimate. The mean of the two
has ``1 / sqrt(2)`` of it.
"""

from __future__ import annotations

import math

import numpy as np

from ..rings.geometry import ring_geometry


def ring_images(windows: np.ndarray, radii) -> np.ndarray:
    """(len(radii), H, W, 3) float64 ring light images E_r of every grid point from
    (H, W, 2R+1, 2R+1, 3) windows (every point lit; frames crosstalk-free, so this is exactly
    what the dataset's stack gives); NaN where a point has no ring member on the grid."""
    height, width, size = windows.shape[:3]
    radius = size // 2
    images = np.zeros((len(radii), height, width, 3))
    for index, r in enumerate(radii):
        total = np.zeros((height, width, 3))
        count = np.zeros((height, width, 1))
        for dy, dx in ring_geometry(float(r)).offsets:
            if max(abs(dy), abs(dx)) > radius or abs(dy) >= height or abs(dx) >= width:
                continue  # beyond the window, or no point of the grid has this member on it
            # Point p is lit by q = p + d, seen at offset -d of q's window.
            ys = slice(max(0, -dy), min(height, height - dy))
            xs = slice(max(0, -dx), min(width, width - dx))
            total[ys, xs] += windows[ys.start + dy:ys.stop + dy, xs.start + dx:xs.stop + dx, radius - dy, radius - dx]
            count[ys, xs] += 1
        with np.errstate(invalid="ignore", divide="ignore"):
            images[index] = total / count
    return images


def transient_images(windows: np.ndarray, radii) -> np.ndarray:
    """(len(radii), H, W, 3) T_r = E_r - E_{r+1} for integer ``radii`` (see :func:`ring_images`)."""
    radii = np.asarray(radii, np.float64)
    rings = ring_images(windows, np.concatenate([radii, [radii[-1] + 1.0]]))
    return rings[:-1] - rings[1:]


def relative_noise(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) relative noise of one estimate per leading index, from two independent estimates
    ``a`` and ``b`` (k, ...) of the same images (the module's figure; NaN pixels ignored)."""
    out = np.empty(a.shape[0])
    for index, (first, second) in enumerate(zip(a, b)):
        valid = np.isfinite(first) & np.isfinite(second)
        spread = math.sqrt(np.mean((first[valid] - second[valid]) ** 2) / 2)
        level = math.sqrt(np.mean(((first[valid] + second[valid]) / 2) ** 2))
        out[index] = spread / level if level > 0 else math.inf
    return out


def transient_noise(windows_a: np.ndarray, windows_b: np.ndarray, radii) -> np.ndarray:
    """(len(radii),) relative noise of T_r of one of two independent simulations' windows."""
    return relative_noise(transient_images(windows_a, radii), transient_images(windows_b, radii))
