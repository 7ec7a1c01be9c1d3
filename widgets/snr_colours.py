"""One colour scale for signal-to-noise ratios, shared by the SNR map, its colour bar and the
scrub bar's SNR strip: matplotlib's perceptually uniform ``viridis`` (as pyqtgraph ships it)
over SNR 0 .. 10, values above 10 drawn as 10."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg

SNR_COLORMAP = "viridis"
SNR_LEVELS = (0.0, 10.0)
TRUSTED_SNR = 3.0
"""SNR from which a transient counts as signal (the Layers tab's trusted flag uses the same)."""
UNDEFINED_RGB = (72, 72, 80)
"""Pixels without an SNR (fewer than 2 ring members): the image views' undefined grey."""


def snr_colormap() -> pg.ColorMap:
    return pg.colormap.get(SNR_COLORMAP)


def snr_rgb(snr: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 colours of ``snr`` (any shape) on the shared scale; NaN grey."""
    snr = np.asarray(snr, np.float64)
    low, high = SNR_LEVELS
    fraction = np.clip((np.nan_to_num(snr, nan=low, posinf=high) - low) / (high - low), 0.0, 1.0)
    rgb = snr_colormap().map(fraction.ravel(), mode="byte")[:, :3].reshape(*snr.shape, 3)
    rgb[np.isnan(snr)] = UNDEFINED_RGB
    return np.ascontiguousarray(rgb, np.uint8)
