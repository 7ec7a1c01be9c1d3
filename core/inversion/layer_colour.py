"""Each fitted layer's colour and its two-sigma region in xy.

A layer's colour is what the format defines as the truth (docs/format/dataset.md): the thick-slab reflectance of its fitted
material (adding-doubling). Its region joins two things: the chromaticities of every combination
of per-channel absorptions within the channels' profile-likelihood intervals (:mod:`.fit`; a
convex polygon, the image of a box), and, when the channels were fitted jointly (:mod:`.joint`),
the joint fit's two-sigma ellipse around its colour where that fit's chi-square is close to
quadratic (:data:`QUADRATIC_SPREAD`). The box treats the channels as independent, which misstates
the colour's uncertainty where their errors move together, and the ellipse is a quadratic
approximation, which fails where an absorption is weakly determined: their convex hull keeps
both, so the region never shrinks below what either shows.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..colour.chroma import chromaticity, srgb_swatch
from ..simulate.adding_doubling import thick_slab_reflectance
from .fit import MUA_BOUNDS, ChannelFit
from .forward import Structure
from .joint import JointFit, chromaticity_ellipse
from .white_mc import SlabOptics

CHANNEL_NAMES = ("R", "G", "B")
GRADIENT_STEP = 1e-4
"""Step in log absorption of the central differences that give a colour's gradient."""
QUADRATIC_SPREAD = 0.5
"""The joint fit's ellipse joins a layer's region only where the Fisher standard deviation of every
channel's log absorption is at most this (two sigma within a factor e either way): there the
chi-square is close to quadratic (the calibration test of :mod:`.joint`). A weakly absorbing
channel's is not (its chi-square is flat towards no absorption and steep away from it): the Wald
ellipse then spans colours far outside the profile-likelihood box (layers3's top, red near 0 with
standard deviation 284 in log: 1.4 wide in xy)."""


@dataclass(frozen=True)
class InvertedLayer:
    """One fitted layer.

    Attributes
    ----------
    top, bottom
        Depth range, grid steps.
    mus
        Scattering coefficient, per grid step.
    mua, mua_interval
        (3,) fitted absorption and (3, 2) its two-sigma range per channel, per grid step.
    determined
        False when some channel's absorption is not bounded by the data; ``reason`` says which.
    rgb, xy
        Thick-slab colour (linear, the dataset's colourspace) and its chromaticity.
    region
        (K, 2) the two-sigma region in xy, a convex polygon.
    swatch
        8-bit sRGB of ``rgb``.
    allowed_width
        The width (as :attr:`region_width`) of the two-sigma region the data alone allow
        (:mod:`.limit`); NaN when not computed.
    limit
        Why the data cannot place this layer within :data:`.limit.TOLERANCE_XY` ("" when they can).
    """

    top: float
    bottom: float
    mus: float
    mua: np.ndarray
    mua_interval: np.ndarray
    determined: bool
    reason: str
    rgb: np.ndarray
    xy: np.ndarray
    region: np.ndarray
    swatch: tuple[int, int, int]
    allowed_width: float = math.nan
    limit: str = ""

    @property
    def region_width(self) -> float:
        """The two-sigma region's larger extent in x or y (NaN without a region)."""
        return float(np.ptp(self.region, axis=0).max()) if len(self.region) else float("nan")


def layer_colours(fits: list[ChannelFit], structure: Structure, optics: SlabOptics, colorspace: str,
                  joint: JointFit | None = None) -> list[InvertedLayer]:
    """The layers of ``structure`` as ``fits`` (one per channel) found them; with ``joint``, each
    layer's absorption and colour are the joint fit's, its intervals grown to hold them and its
    region joined with the joint fit's ellipse."""
    layers = []
    for k, (top, bottom) in enumerate(structure.depth_ranges(optics.depth)):
        mus = float(optics.mus[structure.starts[k]])
        interval = np.array([f.interval[k] for f in fits])
        open_channels = [CHANNEL_NAMES[c] for c, f in enumerate(fits) if f.unbounded[k] or not np.isfinite(f.mua[k])]
        reason = ""
        if open_channels:
            reason = (f"absorption in {', '.join(open_channels)} is not bounded by the data (the two-sigma range "
                      f"reaches {MUA_BOUNDS[1]:g} per grid step): the layers above absorb that light, or too "
                      f"few rings stand out of the noise")
        mua = np.array([f.mua[k] for f in fits]) if joint is None else joint.mua[:, k]
        filled = np.where(np.isfinite(mua), mua, MUA_BOUNDS[1])
        colour = lambda absorption: thick_slab_reflectance(np.full(absorption.shape, mus), absorption, optics.g,
                                                           optics.n)
        rgb = colour(filled)
        xy = chromaticity(rgb, colorspace)
        # A channel's thick-slab colour depends on its own absorption alone: the corners of the
        # box of absorption ranges are combinations of each channel's colour at its range's ends
        # (6 adding-doubling solutions, not 24: each costs about 5 ms).
        ends = colour(interval.ravel()).reshape(interval.shape)  # (C, 2)
        corners = np.array(list(itertools.product(*ends)))  # (2^C, C) colours
        points = [chromaticity(corners, colorspace)]
        if joint is not None:
            interval = np.stack([np.minimum(interval[:, 0], mua), np.maximum(interval[:, 1], mua)], axis=1)
            points += [xy[None]]
            covariance = joint.layer_covariance(k)
            if (not open_channels and not joint.at_bound[:, k].any()
                    and np.all(np.sqrt(np.diagonal(covariance)) <= QUADRATIC_SPREAD)):
                points.append(chromaticity_ellipse(xy, chromaticity_gradient(mus, mua, optics, colorspace),
                                                   covariance))
        layers.append(InvertedLayer(top, bottom, mus, mua, interval, not open_channels, reason, rgb, xy,
                                    _hull(np.vstack(points)), srgb_swatch(rgb, colorspace)))
    return layers


def widened(layer: InvertedLayer, other: InvertedLayer) -> InvertedLayer:
    """``layer`` with its region and absorption ranges grown to cover ``other`` (the same layer in
    a rival structure); determined only if both are."""
    region = _hull(np.vstack([layer.region, other.region, layer.xy[None], other.xy[None]]))
    interval = np.stack([np.minimum(layer.mua_interval[:, 0], other.mua_interval[:, 0]),
                         np.maximum(layer.mua_interval[:, 1], other.mua_interval[:, 1])], axis=1)
    determined = layer.determined and other.determined
    reason = layer.reason or other.reason
    if not determined and not reason:
        reason = "not determined under a structure that fits as well"
    return replace(layer, region=region, mua_interval=interval, determined=determined, reason=reason)


def joined(region: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The convex hull of ``region`` (K, 2) and ``points`` (N, 2); ``region`` itself without points."""
    return _hull(np.vstack([region, points])) if len(points) else region


def region_contains(region: np.ndarray, xy) -> bool:
    """Whether the polygon ``region`` (K, 2) contains ``xy`` (on the edge counts)."""
    if len(region) < 3:
        return False
    return cv2.pointPolygonTest(region.astype(np.float32).reshape(-1, 1, 2), (float(xy[0]), float(xy[1])),
                                False) >= 0


def _hull(points: np.ndarray) -> np.ndarray:
    """(K, 2) float64 convex hull of the finite ``points`` (N, 2); empty without any."""
    points = points[np.isfinite(points).all(axis=1)]
    if not len(points):
        return np.zeros((0, 2))
    return cv2.convexHull(points.astype(np.float32)).reshape(-1, 2).astype(np.float64)


def chromaticity_gradient(mus: float, mua: np.ndarray, optics: SlabOptics, colorspace: str) -> np.ndarray:
    """(2, C) derivatives of the xy chromaticity of a layer's thick-slab colour (scattering ``mus``,
    absorption ``mua`` (C,) per grid step, ``optics``' g and n) per unit of each channel's
    ``log mua``: central differences of step :data:`GRADIENT_STEP`. A channel's colour depends on
    its own absorption alone, so the other channels keep their colour at ``mua`` (3 C adding-doubling
    solutions, not 2 C^2)."""
    theta = np.log(np.asarray(mua, np.float64))
    channels = len(theta)
    trials = np.concatenate([theta, theta + GRADIENT_STEP, theta - GRADIENT_STEP])
    rgb = thick_slab_reflectance(np.full(trials.shape, mus), np.exp(trials), optics.g, optics.n).reshape(3, channels)
    columns = []
    for c in range(channels):
        up, down = rgb[0].copy(), rgb[0].copy()
        up[c], down[c] = rgb[1, c], rgb[2, c]
        columns.append((chromaticity(up, colorspace) - chromaticity(down, colorspace)) / (2.0 * GRADIENT_STEP))
    return np.stack(columns, axis=1)
