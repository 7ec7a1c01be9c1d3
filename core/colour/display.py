"""Turning linear radiance images into screen pixels: normalisation, exposure, display encoding.

Pipeline for one (H, W, 3) linear image in a dataset's colourspace::

    levels (low, high)   from the normalisation: per-image or global robust maximum (a
                         percentile of finite values, the paper's display), per-image robust
                         minimum to maximum ("range": a nearly uniform image's structure), log,
                         or manual
    value * 2**exposure  exposure in stops
    colour mode          linear -> sRGB primaries (colour-science matrix) -> (v - low) / (high - low)
                         -> sRGB encoding (colour-science's inverse EOTF, as a 4096-entry table)
    log mode             log10(v / low) / log10(high / low) per channel, no further encoding
    diverging mode       luminance Y / max(|low|, |high|) in [-1, 1] through a blue-white-red
                         map, so negative transient values are shown, not clipped
    one channel          R, G, B or luminance Y alone, (v - low) / (high - low) (or the log
                         scale) through a colour map: grey (sRGB-encoded on linear scales)
                         unless the caller passes a table

Colour maps other than the two built in here (grey, and ColorBrewer RdBu for signed values) come
from the caller as a (256, 3) uint8 table, so that this module needs no GUI library.

NaN (undefined: no ring member, unobserved point) is drawn as :data:`UNDEFINED_RGB`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numba
import numpy as np

from ..colourspaces import colour_module, colourspace_luminance

NORMALISATIONS = ("per-image", "range", "global", "log", "manual")
CHANNELS = ("rgb", "R", "G", "B", "Y")
"""What an image view shows: colour, one channel, or luminance Y (the colourspace's)."""
UNDEFINED_RGB = (72, 72, 80)
"""Display colour of NaN pixels: a neutral dark grey, distinct from black (zero radiance)."""

_ENCODING_TABLE_SIZE = 4096
# ColorBrewer RdBu (11 classes), blue for negative, white at zero, red for positive.
_DIVERGING_ANCHORS = np.array([
    [5, 48, 97], [33, 102, 172], [67, 147, 195], [146, 197, 222], [209, 229, 240], [247, 247, 247],
    [253, 219, 199], [244, 165, 130], [214, 96, 77], [178, 24, 43], [103, 0, 31],
], np.float64)


@dataclass(frozen=True)
class DisplaySettings:
    """How images are mapped to the screen.

    Attributes
    ----------
    normalisation
        One of :data:`NORMALISATIONS`.
    percentile
        Robust maximum percentile (of finite channel values, or ``|values|`` when diverging).
    manual_levels
        (low, high) linear radiance for ``"manual"``.
    exposure_stops
        Multiplies values by 2**exposure_stops before the levels apply.
    diverging
        Show signed luminance on a diverging map instead of colour.
    log_decades
        Dynamic range of ``"log"``: low = high / 10**log_decades.
    channel
        One of :data:`CHANNELS`; ignored when ``diverging`` (which always shows luminance).
    """

    normalisation: str = "per-image"
    percentile: float = 99.5
    manual_levels: tuple[float, float] = (0.0, 1.0)
    exposure_stops: float = 0.0
    diverging: bool = False
    log_decades: float = 3.0
    channel: str = "rgb"

    def __post_init__(self):
        if self.normalisation not in NORMALISATIONS:
            raise ValueError(f"normalisation must be one of {NORMALISATIONS}, got {self.normalisation!r}")
        if not 0 < self.percentile <= 100:
            raise ValueError(f"percentile must be in (0, 100], got {self.percentile}")
        if self.log_decades <= 0:
            raise ValueError(f"log_decades must be > 0, got {self.log_decades}")
        if self.channel not in CHANNELS:
            raise ValueError(f"channel must be one of {CHANNELS}, got {self.channel!r}")

    @property
    def scalar(self) -> bool:
        """Whether images are shown as one value per pixel through a colour map."""
        return self.diverging or self.channel != "rgb"

    def with_changes(self, **changes) -> "DisplaySettings":
        return replace(self, **changes)


def robust_maximum(values: np.ndarray, percentile: float, signed: bool = False) -> float:
    """The ``percentile`` of the finite entries of ``values`` (of ``|values|`` when ``signed``),
    or 0 when none is finite. Any shape; all channels count."""
    flat = np.asarray(values, np.float32).ravel()
    flat = flat[np.isfinite(flat)]
    if signed:
        flat = np.abs(flat)
    if flat.size == 0:
        return 0.0
    return float(np.percentile(flat, percentile))


def robust_range(values: np.ndarray, percentile: float) -> tuple[float, float]:
    """The ``100 - percentile`` and ``percentile`` percentiles of the finite entries of
    ``values`` (any shape; all channels count), or (0, 0) when none is finite."""
    flat = np.asarray(values, np.float32).ravel()
    flat = flat[np.isfinite(flat)]
    if flat.size == 0:
        return (0.0, 0.0)
    low, high = np.percentile(flat, [100.0 - percentile, percentile])
    return (float(low), float(high))


def display_levels(values: np.ndarray, settings: DisplaySettings, colorspace: str = "sRGB") -> tuple[float, float]:
    """(low, high) for ``values`` (..., 3) linear RGB in ``colorspace`` (one image, or a whole
    stack for ``"global"``), over the values shown (:func:`shown_values`).

    Linear modes give (0, robust max), or (-m, m) when diverging; ``"range"`` gives the
    (100 - percentile, percentile) percentiles (as ``"per-image"`` when diverging, or where
    they are equal); log gives (max / 10**decades, max); manual gives the user's levels. A zero
    maximum becomes 1 so that an all-black image stays black instead of dividing by zero.
    """
    if settings.normalisation == "manual":
        return (float(settings.manual_levels[0]), float(settings.manual_levels[1]))
    if settings.scalar:
        values = shown_values(values, settings, colorspace)
    if settings.normalisation == "range" and not settings.diverging:
        low, high = robust_range(values, settings.percentile)
        if high > low:
            return (low, high)
    high = robust_maximum(values, settings.percentile, signed=settings.diverging)
    if not high > 0:
        high = 1.0
    if settings.normalisation == "log":
        return (high / 10.0**settings.log_decades, high)
    return (-high, high) if settings.diverging else (0.0, high)


def shown_values(image: np.ndarray, settings: DisplaySettings, colorspace: str = "sRGB") -> np.ndarray:
    """The values a scalar view shows of ``image`` (..., 3) linear RGB in ``colorspace``:
    (...) float32, the channel or the luminance Y (always Y when diverging); the image itself
    for the colour view."""
    image = np.asarray(image, np.float32)
    if settings.diverging or settings.channel == "Y":
        return image @ _luminance_weights(colorspace)
    if settings.channel == "rgb":
        return image
    return image[..., "RGB".index(settings.channel)]


def render(image: np.ndarray, levels: tuple[float, float], settings: DisplaySettings,
           colorspace: str = "sRGB", lut: np.ndarray | None = None) -> np.ndarray:
    """Screen pixels for ``image`` (H, W, 3) linear radiance: (H, W, 3) uint8 sRGB-encoded for
    the colour view; for a scalar view (:attr:`DisplaySettings.scalar`) the value's position
    between the levels through ``lut`` ((n, 3) uint8 colour map, low to high; default: grey,
    sRGB-encoded on linear scales, or RdBu when diverging)."""
    low, high = levels
    gain = np.float32(2.0**settings.exposure_stops)
    if not settings.scalar and settings.normalisation != "log":
        # The default view, drawn at every step of a scrub: one compiled pass over the image.
        return _colour_pass(np.asarray(image, np.float32), gain, _to_srgb_matrix(colorspace), np.float32(low),
                            np.float32(1.0 / (high - low if high != low else 1.0)), _srgb_encoding_table(),
                            np.array(UNDEFINED_RGB, np.uint8))
    image = np.asarray(image, np.float32) * gain
    undefined = ~np.isfinite(image).all(axis=-1)
    image = np.where(undefined[..., None], 0, image)
    if settings.diverging:
        pixels = _diverging(shown_values(image, settings, colorspace), max(abs(low), abs(high)), lut)
    elif settings.channel != "rgb":
        values = shown_values(image, settings, colorspace)
        if settings.normalisation == "log":
            position = _log_position(values, low, high)
        else:
            position = (values - np.float32(low)) * np.float32(1.0 / (high - low if high != low else 1.0))
        pixels = _scalar_colours(np.clip(position, 0, 1), settings, lut)
    else:
        pixels = _log_encoded(image, low, high)
    pixels[undefined] = UNDEFINED_RGB
    return pixels


@numba.njit(parallel=True, cache=True, nogil=True)
def _colour_pass(image, gain, matrix, low, inverse_span, table, undefined):  # pragma: no cover - compiled
    """(H, W, 3) uint8: ``table`` at ((matrix @ (gain * v) - low) * inverse_span) of each pixel
    v of (H, W, 3) float32 ``image``, clipped to the table, in float32 as the numpy path computes
    it; ``undefined`` where any channel is not finite."""
    height, width = image.shape[0], image.shape[1]
    pixels = np.empty((height, width, 3), np.uint8)
    last = table.size - 1
    for y in numba.prange(height):
        for x in range(width):
            r = image[y, x, 0] * gain
            g = image[y, x, 1] * gain
            b = image[y, x, 2] * gain
            if not (np.isfinite(r) and np.isfinite(g) and np.isfinite(b)):
                for c in range(3):
                    pixels[y, x, c] = undefined[c]
                continue
            for c in range(3):
                value = matrix[c, 0] * r + matrix[c, 1] * g + matrix[c, 2] * b
                scaled = (value - low) * inverse_span * np.float32(last) + np.float32(0.5)
                index = int(min(max(scaled, np.float32(0.0)), np.float32(last)))
                pixels[y, x, c] = table[index]
    return pixels


def scalar_lut(settings: DisplaySettings, lut: np.ndarray | None = None, entries: int = 256) -> np.ndarray:
    """(entries, 3) uint8: the colours :func:`render` gives a scalar view's values from the low
    level to the high one (for a colour bar that matches the pixels)."""
    position = np.linspace(0.0, 1.0, entries, dtype=np.float32)
    if settings.diverging:
        return _diverging(2 * position - 1, 1.0, lut)
    return _scalar_colours(position, settings, lut)


def _scalar_colours(position: np.ndarray, settings: DisplaySettings, lut: np.ndarray | None) -> np.ndarray:
    """(..., 3) uint8 colours of a one-channel view at ``position`` in [0, 1]: ``lut``, or grey."""
    return _grey(position, settings.normalisation != "log") if lut is None else _through(position, lut)


def warm_up_display() -> None:
    """Load the compiled display kernels (:func:`render`'s colour pass, :func:`negative_fraction`)
    for the images the explorer draws ((H, W, 3) float32), so that the first image drawn does not
    compile them in the GUI thread (1.6 s with an empty numba cache, seen in a review)."""
    image = np.zeros((2, 2, 3), np.float32)
    render(image, (0.0, 1.0), DisplaySettings())
    negative_fraction(image)


def negative_fraction(image: np.ndarray) -> float:
    """Fraction of finite values below zero in ``image`` (any shape): what a non-diverging
    display clips to black, reported so that the clipping is never silent."""
    finite, negative = _finite_and_negative(np.ravel(image))
    return negative / finite if finite else 0.0


@numba.njit(parallel=True, cache=True, nogil=True)
def _finite_and_negative(values):  # pragma: no cover - compiled
    """Counts of finite and of negative finite values in flat float ``values``, in one pass (at
    every scrub step: numpy's masks and copies took 4 ms of an 800 x 800 step)."""
    finite = 0
    negative = 0
    for i in numba.prange(values.size):
        value = values[i]
        if np.isfinite(value):
            finite += 1
            if value < 0:
                negative += 1
    return finite, negative


def _log_position(values: np.ndarray, low: float, high: float) -> np.ndarray:
    """log10(v / low) / log10(high / low): 0 at ``low`` (and below), 1 at ``high``."""
    low = low if low > 0 else high * 1e-3
    high = high if high > low else low * 10
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log10(np.maximum(values, np.float32(low)) / np.float32(low)) / np.float32(math.log10(high / low))


def _log_encoded(image: np.ndarray, low: float, high: float) -> np.ndarray:
    return np.clip(_log_position(image, low, high) * 255 + 0.5, 0, 255).astype(np.uint8)


def _through(position: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Colours of ``position`` in [0, 1] (any shape) from the nearest entry of ``lut`` (n, 3)."""
    index = np.clip(position * (len(lut) - 1) + 0.5, 0, len(lut) - 1).astype(np.int32)
    return np.asarray(lut, np.uint8)[index]


def _diverging(luminance: np.ndarray, magnitude: float, lut: np.ndarray | None = None) -> np.ndarray:
    magnitude = magnitude if magnitude > 0 else 1.0
    position = np.clip(luminance / np.float32(magnitude), -1, 1)
    return _rdbu(position) if lut is None else _through((position + 1) / 2, lut)


def _rdbu(position: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 ColorBrewer RdBu colours of ``position`` in [-1, 1] (white at 0)."""
    anchors = np.linspace(-1, 1, len(_DIVERGING_ANCHORS))
    channels = [np.interp(position, anchors, _DIVERGING_ANCHORS[:, c]) for c in range(3)]
    return (np.stack(channels, axis=-1) + 0.5).astype(np.uint8)


def diverging_lut(entries: int = 256) -> np.ndarray:
    """(entries, 3) uint8: the built-in signed map (RdBu), negative to positive."""
    return _rdbu(np.linspace(-1, 1, entries))


def _grey(position: np.ndarray, encoded: bool) -> np.ndarray:
    """(..., 3) uint8 grey of ``position`` in [0, 1]: sRGB-encoded like the colour view (a grey
    image looks the same in its R view), or a plain ramp for the log scale, which is not encoded
    either."""
    if not encoded:
        return np.repeat(np.clip(position * 255 + 0.5, 0, 255).astype(np.uint8)[..., None], 3, axis=-1)
    index = np.clip(position * (_ENCODING_TABLE_SIZE - 1) + 0.5, 0, _ENCODING_TABLE_SIZE - 1).astype(np.int32)
    return np.repeat(_srgb_encoding_table()[index][..., None], 3, axis=-1)


@functools.cache
def _srgb_encoding_table() -> np.ndarray:
    """(4096,) uint8: 8-bit sRGB code of linear ``i / 4095`` (colour-science's inverse EOTF)."""
    code = colour_module().models.eotf_inverse_sRGB(np.linspace(0.0, 1.0, _ENCODING_TABLE_SIZE))
    return np.clip(np.round(code * 255), 0, 255).astype(np.uint8)


@functools.cache
def _to_srgb_matrix(colorspace: str) -> np.ndarray:
    """(3, 3) float32 matrix from linear ``colorspace`` RGB to linear sRGB (Bradford-adapted)."""
    colour = colour_module()
    if colorspace == "sRGB":
        return np.eye(3, dtype=np.float32)
    source = colour.RGB_COLOURSPACES[colorspace]
    target = colour.RGB_COLOURSPACES["sRGB"]
    return colour.matrix_RGB_to_RGB(source, target, chromatic_adaptation_transform="Bradford").astype(np.float32)


@functools.cache
def _luminance_weights(colorspace: str) -> np.ndarray:
    """(3,) float32: relative luminance Y of linear ``colorspace`` RGB (row Y of RGB->XYZ)."""
    return colourspace_luminance(colorspace).astype(np.float32)


HISTOGRAM_BINS = 128


def value_histogram(image: np.ndarray, bins: int = HISTOGRAM_BINS) -> tuple[np.ndarray, np.ndarray]:
    """Histogram of the finite channel values of an (H, W, 3) image.

    Returns ``(edges (bins + 1,), counts (bins,))`` over [min, max] of those values (a unit
    range around a constant image; empty arrays when no value is finite).
    """
    values = np.asarray(image, np.float32).ravel()  # no copy of a float32 image
    values = values[np.isfinite(values)]
    if not len(values):
        return np.zeros(0), np.zeros(0)
    low, high = float(values.min()), float(values.max())
    if high <= low:
        low, high = low - 0.5, high + 0.5
    counts, edges = np.histogram(values, bins=bins, range=(low, high))
    return edges.astype(np.float64), counts  # float64: plot ranges in float32 overflow in pyqtgraph
