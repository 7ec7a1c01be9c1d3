"""What the live view shows of a raw camera frame: display pixels, saturation and a histogram.

Computed here, off the GUI thread, so that the wizard only draws: the frame is scaled linearly from
the black level to the saturation level, square-rooted (so that faint light stays visible; a
display choice, the data stay linear), and every pixel with a channel at or above the saturation
level is painted :data:`SATURATED_RGB`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SATURATED_RGB = (255, 0, 64)
LIVE_FPS = 4.0
"""Frames per second the live view asks for (fewer when exposures are longer)."""


@dataclass(frozen=True, eq=False)
class LiveFrame:
    """A summarised camera frame.

    Attributes
    ----------
    pixels
        (rows, cols, 3) uint8 RGB for display, saturated pixels in SATURATED_RGB.
    histogram, edges
        (bins,) int64 counts of all raw samples (every channel) and the (bins + 1,) raw-count edges
        from the black level to the saturation level (samples outside are counted in the end bins).
    saturated_fraction
        Fraction of pixels with a saturated channel.
    peak
        Largest raw value above the black level (counts).
    exposure
        Seconds.
    """

    pixels: np.ndarray
    histogram: np.ndarray
    edges: np.ndarray
    saturated_fraction: float
    peak: float
    exposure: float


def summarise_frame(frame: np.ndarray, black_level: float, saturation_level: float, exposure: float,
                    bins: int = 64) -> LiveFrame:
    """Summarise a raw ``frame`` (rows, cols) or (rows, cols, 3) for the live view.

    >>> live = summarise_frame(np.array([[64.0, 4095.0]]), 64.0, 4095.0, 0.01, bins=4)
    >>> live.histogram.tolist(), live.saturated_fraction, live.pixels[0, 1].tolist()
    ([3, 0, 0, 3], 0.5, [255, 0, 64])
    """
    frame = np.asarray(frame, np.float32)
    if frame.ndim == 2:
        frame = np.repeat(frame[:, :, None], 3, axis=2)
    span = max(saturation_level - black_level, 1.0)
    scaled = np.sqrt(np.clip((frame - black_level) / span, 0.0, 1.0))
    pixels = np.round(scaled * 255).astype(np.uint8)
    saturated = (frame >= saturation_level - 0.5).any(axis=-1)
    pixels[saturated] = SATURATED_RGB
    edges = np.linspace(black_level, saturation_level, bins + 1)
    histogram = np.bincount(np.clip(np.searchsorted(edges, frame.ravel(), side="right") - 1, 0, bins - 1),
                            minlength=bins).astype(np.int64)
    return LiveFrame(pixels, histogram, edges, float(saturated.mean()), float(frame.max() - black_level), exposure)
