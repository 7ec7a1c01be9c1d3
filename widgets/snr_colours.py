"""One colour scale for signal-to-noise ratios, shared by the SNR map, its colour bar and the
scrub bar's SNR strip: over SNR 0 .. 10, values above 10 drawn as 10, through one colour map for
all three (matplotlib's perceptually uniform ``viridis`` unless the user picks another of
:data:`ringlight.widgets.colormaps.MAPS` ``["snr"]``)."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg

from .colormaps import MAPS

SNR_LEVELS = (0.0, 10.0)
TRUSTED_SNR = 3.0
"""SNR from which a transient counts as signal (the Layers tab's trusted flag uses the same)."""
UNDEFINED_RGB = (72, 72, 80)
"""Pixels without an SNR (fewer than 2 ring members): the image views' undefined grey."""
_current = {"name": MAPS["snr"][0]}


def snr_colormap_name() -> str:
    return _current["name"]


def set_snr_colormap(name: str) -> None:
    """Use map ``name`` (one of ``MAPS["snr"]``) for every SNR display from now on."""
    if name not in MAPS["snr"]:
        raise ValueError(f"SNR colour map must be one of {MAPS['snr']}, got {name!r}")
    _current["name"] = name


def snr_colormap() -> pg.ColorMap:
    name = _current["name"]
    if name == "grey":  # a plain ramp: SNR is not a radiance, so no display encoding
        return pg.ColorMap([0.0, 1.0], [(0, 0, 0), (255, 255, 255)], name=name)
    return pg.colormap.get(name)


def snr_rgb(snr: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 colours of ``snr`` (any shape) on the shared scale; NaN grey."""
    snr = np.asarray(snr, np.float64)
    low, high = SNR_LEVELS
    fraction = np.clip((np.nan_to_num(snr, nan=low, posinf=high) - low) / (high - low), 0.0, 1.0)
    rgb = snr_colormap().map(fraction.ravel(), mode="byte")[:, :3].reshape(*snr.shape, 3)
    rgb[np.isnan(snr)] = UNDEFINED_RGB
    return np.ascontiguousarray(rgb, np.uint8)
