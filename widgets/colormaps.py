"""The colour maps a scalar image view offers, by kind, as pyqtgraph ships them.

Three kinds of scalar view: one channel or luminance (sequential maps), signed luminance
(diverging maps, white or grey at zero) and the SNR map (sequential). The first entry of each kind
is its default. "grey" and "RdBu" are the display pipeline's own (:mod:`ringlight.core.colour.display`);
the others are pyqtgraph's bundled maps (matplotlib's perceptually uniform ones and colorcet's).
"""

from __future__ import annotations

import functools

import numpy as np
import pyqtgraph as pg
from ringlight.core.colour.display import DisplaySettings, diverging_lut, scalar_lut

KINDS = ("channel", "signed", "snr")
MAPS = {
    "channel": ("grey", "viridis", "inferno", "magma", "cividis", "turbo"),
    "signed": ("RdBu", "CET-D1A", "CET-D4", "CET-D10"),
    "snr": ("viridis", "inferno", "cividis", "turbo", "grey"),
}
"""Map names offered for each kind, the default first."""
LUT_ENTRIES = 256


@functools.cache
def lut(name: str) -> np.ndarray | None:
    """(256, 3) uint8 table of ``name``, low to high; None for "grey" (the display pipeline's own
    sRGB-encoded grey, so that a channel looks as it does in the colour view)."""
    if name == "grey":
        return None
    if name == "RdBu":
        return diverging_lut(LUT_ENTRIES)
    table = pg.colormap.get(name).getLookupTable(0.0, 1.0, LUT_ENTRIES, alpha=False)
    return np.ascontiguousarray(table[:, :3], np.uint8)


def bar_colormap(name: str, settings: DisplaySettings) -> pg.ColorMap:
    """A ColorMap for the colour bar of a scalar view shown with map ``name`` under ``settings``:
    the colours the image's pixels get, low level to high."""
    table = scalar_lut(settings, lut(name), LUT_ENTRIES)
    return pg.ColorMap(np.linspace(0.0, 1.0, LUT_ENTRIES), table, name=f"{name} {settings.normalisation}")
