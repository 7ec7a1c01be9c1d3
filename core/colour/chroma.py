"""Chromaticity of transient images over a region, and layer colours recovered from picked radii.

Transient images integrate colour along ever longer, deeper paths (paper Sec. 4.2), so the
chromaticity of the region-mean transient image moves with the radius (the *trajectory*), and the
colours of deeper layers show in how it moves between picked radii r_1 < r_2 < ... .

Region means are of linear RGB over the region's pixels where the transient is defined; the
chromaticity of a mean is taken (never the mean of per-pixel chromaticities, which noise and
negative transient values make meaningless). RGB -> XYZ -> xy is colour-science's, for the
dataset's colourspace.

Two recovery methods, for picked transient images k = 1..K with region-mean RGB m_k and
chromaticity c_k = xy(m_k):

``paper``
    Nishino et al. take "the mean chromaticities of each image and then their differences". A
    difference of chromaticities is a direction, not a colour; we read it as a displacement from
    the colourspace's white point w:  L_1 = c_1,  L_k = w + (c_k - c_{k-1}) for k >= 2.
``radiance``
    Each m_k is normalised to unit luminance, n_k = m_k / Y(m_k), so that the fall-off of longer
    paths cancels. If transient k is a luminance-weighted mix of the colour seen at k-1 and the
    newly reached layer, n_k = (1 - a) n_{k-1} + a L_k; with a = 1/2 (half of the light new)
    L_k = n_k + (n_k - n_{k-1}) = 2 n_k - n_{k-1};  L_1 = n_1.  Its chromaticity is reported.

Each layer is given as xy, linear RGB of unit luminance, and an 8-bit sRGB swatch (out-of-gamut
colours are desaturated towards white until displayable).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..colourspaces import colour_module, colourspace_chromaticities, colourspace_luminance
from ..errors import RinglightError
from ..rings.stacks import Stack

METHODS = ("paper", "radiance")
MIN_SNR = 3.0
"""Transients whose region-mean luminance is below MIN_SNR standard errors are flagged."""


class LayerError(RinglightError):
    """Layer recovery asked for something the stack or region cannot give."""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Region-mean colour of every transient image of a stack.

    Attributes
    ----------
    radii
        (n,) radii in grid steps.
    mean_rgb
        (n, 3) region-mean linear RGB (NaN when no pixel of the region is defined).
    xy
        (n, 2) CIE 1931 chromaticity of ``mean_rgb``; NaN when its luminance is not positive.
    luminance
        (n,) relative luminance Y of ``mean_rgb``.
    snr
        (n,) Y over its standard error (std of per-pixel Y / sqrt(pixels)); inf for one pixel
        with positive Y, NaN without pixels.
    pixels
        (n,) region pixels with a defined transient.
    mean_ring_points
        (n,) mean ring points behind E_r over those pixels.
    """

    radii: np.ndarray
    mean_rgb: np.ndarray
    xy: np.ndarray
    luminance: np.ndarray
    snr: np.ndarray
    pixels: np.ndarray
    mean_ring_points: np.ndarray
    colorspace: str

    def trusted(self, index: int) -> bool:
        return bool(self.luminance[index] > 0 and self.snr[index] >= MIN_SNR)


@dataclass(frozen=True)
class LayerColour:
    """One recovered layer: the radius it comes from, its colour, and whether to trust it."""

    radius: float
    xy: tuple[float, float]
    rgb: tuple[float, float, float]
    srgb8: tuple[int, int, int]
    trusted: bool
    note: str = ""


@dataclass(frozen=True)
class LayerResult:
    """Layers recovered by ``method`` from ``radii``, with xy errors against truth when known."""

    method: str
    radii: tuple[float, ...]
    layers: tuple[LayerColour, ...]
    truth_xy: tuple[tuple[float, float], ...] | None = None
    truth_srgb8: tuple[tuple[int, int, int], ...] | None = None
    errors: tuple[float, ...] | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)


def colour_unavailable(channels: tuple[str, ...]) -> str | None:
    """Why a dataset read from ``channels`` has no colour to recover, or None when it has.

    A monochrome camera's dataset (one channel) is grey, R = G = B: every transient image has the
    white point's chromaticity, so layer colours need an RGB camera. The Layers tab shows this
    line in place of a result.

    Examples
    --------
    >>> colour_unavailable(("R", "G", "B")) is None
    True
    >>> colour_unavailable(("Y",))
    'the dataset is monochrome (frames of one channel, Y): layer colours need an RGB camera'
    """
    if len(channels) == 1:
        return f"the dataset is monochrome (frames of one channel, {channels[0]}): layer colours need an RGB camera"
    return None


def require_colour(channels: tuple[str, ...]) -> None:
    """Raise :class:`LayerError` with :func:`colour_unavailable`'s line for a monochrome dataset."""
    if (reason := colour_unavailable(channels)) is not None:
        raise LayerError(reason)


def chromaticity(rgb: np.ndarray, colorspace: str) -> np.ndarray:
    """CIE 1931 xy of linear ``rgb`` (..., 3) in ``colorspace``: (..., 2); NaN where the
    luminance Y <= 0 or the tristimulus sum X + Y + Z <= 0 (no meaningful chromaticity).

    Examples
    --------
    >>> chromaticity(np.array([1.0, 1.0, 1.0]), "sRGB").round(4).tolist()
    [0.3127, 0.329]
    """
    colour = colour_module()
    xyz = colour.RGB_to_XYZ(np.asarray(rgb, np.float64), colorspace)
    total = xyz.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = xyz[..., :2] / total[..., None]
    xy[(xyz[..., 1] <= 0) | (total <= 0) | ~np.isfinite(total)] = np.nan
    return xy


def luminance(rgb: np.ndarray, colorspace: str) -> np.ndarray:
    """Relative luminance Y of linear ``rgb`` (..., 3) in ``colorspace``: the Y row of
    colour-science's RGB -> XYZ matrix (no chromatic adaptation, as in :func:`chromaticity`)."""
    return np.asarray(rgb, np.float64) @ colourspace_luminance(colorspace)


def white_point(colorspace: str) -> np.ndarray:
    """(2,) xy of the colourspace's white point (a name in ``colour.RGB_COLOURSPACES``, custom
    colourspaces of :func:`~ringlight.core.colourspaces.parse_colourspace` included)."""
    return colourspace_chromaticities(colorspace)[3]


def trajectory(stack: Stack, region: np.ndarray) -> Trajectory:
    """Region-mean colour of each image of a transient ``stack`` over the (H, W) bool ``region``.

    Raises LayerError when the region has no pixel with a defined transient at any radius.
    """
    region = np.asarray(region, bool)
    if region.shape != stack.images.shape[1:3]:
        raise LayerError(f"region is {region.shape}, the stack's grid is {stack.images.shape[1:3]}")
    values = stack.images[:, region]  # (n, m, 3)
    defined = np.isfinite(values).all(axis=-1)
    pixels = defined.sum(axis=1)
    if not pixels.any():
        raise LayerError("the region has no pixel with a defined transient image (no ring points there)")
    safe = np.where(defined[..., None], values, 0.0).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_rgb = safe.sum(axis=1) / pixels[:, None]
        per_pixel_y = luminance(safe, stack.colorspace)
        mean_y = luminance(mean_rgb, stack.colorspace)
        spread = np.sqrt(np.where(defined, (per_pixel_y - mean_y[:, None]) ** 2, 0).sum(1) / np.maximum(pixels - 1, 1))
        standard_error = spread / np.sqrt(pixels)
        snr = np.where(standard_error > 0, mean_y / standard_error, np.where(mean_y > 0, np.inf, -np.inf))
        ring_points = np.where(defined, stack.counts[:, region], 0).sum(1) / pixels
    snr[pixels == 0] = np.nan
    return Trajectory(
        stack.radii.copy(), mean_rgb, chromaticity(mean_rgb, stack.colorspace), mean_y, snr, pixels,
        ring_points, stack.colorspace,
    )


def radius_indices(path: Trajectory, radii) -> list[int]:
    """Indices of ``radii`` in the trajectory; raises LayerError for a radius not in the stack
    or radii not strictly increasing."""
    radii = [float(r) for r in radii]
    if len(radii) < 1:
        raise LayerError("pick at least one radius")
    if not all(math.isfinite(r) for r in radii):
        raise LayerError(f"picked radii must be finite numbers, got {radii}")
    if any(b <= a for a, b in zip(radii, radii[1:])):
        raise LayerError(f"picked radii must increase strictly, got {radii}")
    indices = []
    for radius in radii:
        index = int(np.argmin(np.abs(path.radii - radius)))
        if abs(path.radii[index] - radius) > 1e-6:
            raise LayerError(
                f"radius {radius:g} is not in the stack (radii {path.radii[0]:g}..{path.radii[-1]:g}, "
                f"{len(path.radii)} images); pick one of its radii"
            )
        indices.append(index)
    return indices


def recover_layers(path: Trajectory, radii, method: str = "paper", truth_rgb=None) -> LayerResult:
    """Layer colours from transients at ``radii`` (see the module docstring for ``method``).

    ``truth_rgb`` (K, 3): reference linear RGB of the layers, top first, to compare with; errors
    are xy distances. Raises LayerError for unknown methods, radii outside the stack, and picked
    transients without a defined colour (no pixel, or luminance <= 0).
    """
    if method not in METHODS:
        raise LayerError(f"method must be one of {METHODS}, got {method!r}")
    indices = radius_indices(path, radii)
    for index in indices:
        if not path.luminance[index] > 0:
            raise LayerError(
                f"the transient at radius {path.radii[index]:g} is "
                f"{'undefined' if not np.isfinite(path.luminance[index]) else 'dark or negative'} "
                f"over the region (mean luminance {path.luminance[index]:.3g}); pick a smaller radius"
            )
    colorspace = path.colorspace
    if method == "paper":
        xy_picked = path.xy[indices]
        layers_xy = [xy_picked[0]] + [white_point(colorspace) + (xy_picked[k] - xy_picked[k - 1])
                                      for k in range(1, len(indices))]
        layers_rgb = [xy_to_unit_rgb(xy, colorspace) for xy in layers_xy]
    else:
        unit = path.mean_rgb[indices] / path.luminance[indices][:, None]
        layers_rgb = [unit[0]] + [2 * unit[k] - unit[k - 1] for k in range(1, len(indices))]
        layers_xy = [chromaticity(rgb, colorspace) for rgb in layers_rgb]
    layers, warnings = [], []
    for k, (index, xy, rgb) in enumerate(zip(indices, layers_xy, layers_rgb)):
        trusted = path.trusted(index) and bool(np.isfinite(xy).all())
        note = ""
        if not path.trusted(index):
            note = f"transient at r = {path.radii[index]:g} has SNR {path.snr[index]:.1f} < {MIN_SNR:g}"
            warnings.append(f"layer {k + 1}: {note}")
        elif not np.isfinite(xy).all():
            note = "no chromaticity: the recovered colour has no positive luminance"
            warnings.append(f"layer {k + 1}: {note}")
        layers.append(LayerColour(
            float(path.radii[index]), _pair(xy), _triple(rgb), srgb_swatch(rgb, colorspace), trusted, note,
        ))
    truth_xy = truth_srgb8 = errors = None
    if truth_rgb is not None:
        truth_srgb8 = tuple(srgb_swatch(np.asarray(rgb, np.float64), colorspace) for rgb in truth_rgb)
        truth_xy = [chromaticity(np.asarray(rgb, np.float64), colorspace) for rgb in truth_rgb]
        errors = tuple(
            float(np.hypot(*(np.asarray(layer.xy) - true))) if k < len(truth_xy) else math.nan
            for k, (layer, true) in enumerate(zip(layers, truth_xy))
        )
        truth_xy = tuple(_pair(xy) for xy in truth_xy)
        if len(truth_rgb) != len(layers):
            warnings.append(f"{len(layers)} radii picked for {len(truth_rgb)} true layers; errors pair them top down")
    return LayerResult(method, tuple(float(path.radii[i]) for i in indices), tuple(layers), truth_xy, truth_srgb8,
                       errors, tuple(warnings))


def propose_radii(path: Trajectory, count: int) -> list[float]:
    """``count`` radii equally spaced (snapped to the stack) from the first trusted radius >= 1
    (r < 1 holds the surface reflection) to the last radius before the signal fades (the last
    of the first run of trusted transients). Raises LayerError when too few are trusted."""
    if count < 1:
        raise LayerError(f"--auto needs at least 1 radius, got {count}")
    candidates = [i for i, r in enumerate(path.radii) if r >= 1.0 - 1e-9]
    trusted = [i for i in candidates if path.trusted(i)]
    if len(trusted) < count:
        raise LayerError(
            f"only {len(trusted)} transient images at r >= 1 are bright enough (SNR >= {MIN_SNR:g}) "
            f"for {count} layers; use a region with more pixels or fewer layers"
        )
    first = trusted[0]
    last = first
    while last + 1 in trusted:
        last += 1
    if last - first + 1 < count:
        last = trusted[count - 1 + trusted.index(first)]
    targets = np.linspace(path.radii[first], path.radii[last], count)
    chosen = sorted({int(np.argmin(np.abs(path.radii - target))) for target in targets})
    return [float(path.radii[i]) for i in chosen]


def xy_to_unit_rgb(xy: np.ndarray, colorspace: str) -> np.ndarray:
    """Linear RGB in ``colorspace`` of chromaticity ``xy`` at luminance Y = 1 (NaN if xy is)."""
    colour = colour_module()
    xy = np.asarray(xy, np.float64)
    if not np.isfinite(xy).all() or xy[1] <= 0:
        return np.full(3, np.nan)
    return colour.XYZ_to_RGB(colour.xyY_to_XYZ([xy[0], xy[1], 1.0]), colorspace)


def srgb_swatch(rgb: np.ndarray, colorspace: str) -> tuple[int, int, int]:
    """8-bit sRGB of linear ``rgb`` in ``colorspace`` scaled to maximum 1; out-of-gamut colours
    are mixed with white (same luminance) until no channel is negative. NaN gives grey 128."""
    colour = colour_module()
    rgb = np.asarray(rgb, np.float64)
    if not np.isfinite(rgb).all():
        return (128, 128, 128)
    srgb = colour.RGB_to_RGB(rgb, colorspace, "sRGB", chromatic_adaptation_transform="Bradford")
    y = float(luminance(srgb, "sRGB"))
    if srgb.min() < 0 and y > 0:
        # Mix towards the grey of equal luminance just enough to clear the gamut boundary.
        grey = np.full(3, y)
        t = max((-(srgb[c]) / (grey[c] - srgb[c]) for c in range(3) if srgb[c] < 0), default=0.0)
        srgb = srgb + t * (grey - srgb)
    srgb = np.clip(srgb, 0, None)
    if srgb.max() > 0:
        srgb = srgb / srgb.max()
    encoded = colour.cctf_encoding(srgb, function="sRGB")
    return tuple(int(v) for v in np.clip(np.round(encoded * 255), 0, 255))


def _pair(xy) -> tuple[float, float]:
    return (float(xy[0]), float(xy[1]))


def _triple(rgb) -> tuple[float, float, float]:
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]))
