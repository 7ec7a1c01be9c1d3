"""What the data alone allow: the width of each layer's colour region that the profile's own noise
permits, the fitted model taken as exact.

A layer's two-sigma region (:mod:`.layer_colour`) is as wide as everything that enters the fit
makes it: the data's noise, the white run's own noise, and the other structures, scatterings and
indices that fit as well. Beside it the user sees the width the *data* allow: the width of the
region the inversion itself would draw if the fitted model were exact and the only one
(:func:`exact_regions`): the channels' profile-likelihood box (:mod:`.fit`) at the data's noise
alone (:func:`.fit.data_sigma`: the measured standard error and the relative floor), joined with
the Fisher ellipse where that is close to quadratic. The Fisher covariance of each channel's
``log mua`` is ``(J^T J)^-1``, ``J`` the derivatives of ``log E(r)`` over the rings the fit used,
each divided by the data's relative standard deviation there (independent between channels unless
replicates measured their covariance; the floor correlated between channels as the joint fit
found); its image in xy by the delta method is an ellipse at :data:`.joint.ELLIPSE_CHI2`.

A region much wider than this is the model's doing (the white run's noise, rivals); a region close
to it is what this profile can say, and a layer whose allowed width exceeds :data:`TOLERANCE_XY`
cannot be pinned closer by any fit of this profile. The Fisher ellipse alone, a local, quadratic
measure, is optimistic where an absorption is weakly determined: layers3's middle layer, whose red
absorption can fall toward zero, had a Fisher width of 0.060 beside a profile-likelihood interval
reaching 8 in log absorption. Where the quadratic approximation holds, a layer's region also joins
the ellipse (:mod:`.layers`): a region is never narrower than what the data alone allow (on a
held-out slab of data noise far below the white run's, a base layer's region came out 0.11 wide
where the data allow 0.18, with its truth 0.088 away).

It holds as far as the data's noise is known. A dataset with replicates measures it in full
(:mod:`.measured`), and there is no floor. Otherwise the measured standard error is the spread of
the region's lit points' rings, which leaves out noise the lit points share (over a simulated
layered region they share one kernel, and the spread is 0.005-0.03 % per ring), and the relative
floor stands in for it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .fit import RELATIVE_FLOOR, ChannelFit, fit_channels
from .forward import SMALLEST_E, Forward
from .joint import ELLIPSE_CHI2, chromaticity_ellipse
from .layer_colour import QUADRATIC_SPREAD, chromaticity_gradient, joined, layer_colours
from .white_mc import SlabOptics

TOLERANCE_XY = 0.02
"""xy width beyond which a layer is reported as not determined to this tolerance by the data."""


def log_absorption_covariance(forward: Forward, mua: np.ndarray, measured: np.ndarray, error: np.ndarray,
                              used: np.ndarray, correlation: float = 0.0, floor: float = RELATIVE_FLOOR,
                              data_covariance: np.ndarray | None = None) -> np.ndarray:
    """(C L, C L) Fisher covariance of ``log mua`` (``mua`` (C, L) per grid step, flattened
    channel-major) at the data's noise alone, over the first ``used[c]`` rings of each channel.

    Each ring's residuals in log E over the channels that use it have the covariance the joint fit
    gives the data (:mod:`.joint`, without the white run's part): the measured relative standard
    errors (``error`` / ``measured``, (R, C)), independent between channels (or their measured
    covariance, ``data_covariance`` (R, C, C)), plus the relative ``floor`` correlated ``correlation``
    between them. A channel with no more rings than layers, or a
    non-finite absorption, has infinite variance (and no covariance with the others)."""
    channels, layers = mua.shape
    fitted = [c for c in range(channels) if int(used[c]) > layers and np.all(np.isfinite(mua[c]))]
    slopes = {}
    for c in fitted:
        profile, derivative = forward.profile(mua[c], derivatives=True)
        slopes[c] = derivative * mua[c] / np.maximum(profile, SMALLEST_E)[:, None]  # d log E / d log mua, (R, L)
    fisher = np.zeros((channels * layers, channels * layers))
    for row in range(int(max((used[c] for c in fitted), default=0))):
        active = [c for c in fitted if row < used[c]]
        scale = measured[row, active]
        if data_covariance is not None:
            data = data_covariance[row][np.ix_(active, active)] / np.outer(scale, scale)
        else:
            data = np.diag((error[row, active] / scale) ** 2)
        covariance = data + floor ** 2 * (correlation + (1.0 - correlation) * np.eye(len(active)))
        jacobian = np.zeros((len(active), channels * layers))
        for i, c in enumerate(active):
            jacobian[i, c * layers:(c + 1) * layers] = slopes[c][row]
        fisher += jacobian.T @ np.linalg.solve(covariance, jacobian)
    result = np.full((channels * layers, channels * layers), math.inf)
    index = np.concatenate([np.arange(c * layers, (c + 1) * layers) for c in fitted]) if fitted else np.zeros(0, int)
    result[np.ix_(index, index)] = np.linalg.pinv(fisher[np.ix_(index, index)])
    return result


def allowed_width(covariance: np.ndarray, mus: float, mua: np.ndarray, optics: SlabOptics, colorspace: str) -> float:
    """The xy width (larger extent in x or y) of the two-sigma ellipse (:data:`.joint.ELLIPSE_CHI2`)
    of a layer's colour whose channels' ``log mua`` (``mua`` (C,)) have ``covariance`` (C, C), by
    the delta method; infinite when a channel that moves the colour has no finite variance."""
    gradient = chromaticity_gradient(mus, mua, optics, colorspace)  # (2, C)
    moving = ~np.all(gradient == 0.0, axis=0)
    covariance = covariance[np.ix_(moving, moving)]
    if not np.all(np.isfinite(covariance)):
        return math.inf
    spread = gradient[:, moving] @ covariance @ gradient[:, moving].T
    return float(2.0 * math.sqrt(ELLIPSE_CHI2 * max(spread[0, 0], spread[1, 1], 0.0)))


class ExactForward:
    """``forward`` (a :class:`.forward.Forward` or :class:`.cell_forward.CellForward`) taken as
    exact: its profile and derivatives, with no noise of its own (the white run's variance and
    covariance zero), for fits that measure what the data alone allow."""

    def __init__(self, forward):
        self._forward = forward

    def __getattr__(self, name):
        return getattr(self._forward, name)

    def variance(self, mua: np.ndarray) -> np.ndarray:
        """(R,) zeros."""
        return np.zeros(len(self._forward.radii))

    def covariance(self, mua: np.ndarray, rings: int | None = None) -> np.ndarray:
        """(rings, C, C) zeros."""
        rings = len(self._forward.radii) if rings is None else rings
        channels = np.asarray(mua).shape[0]
        return np.zeros((rings, channels, channels))


def exact_regions(forward, measured: np.ndarray, error: np.ndarray, colorspace: str,
                  floor: float = RELATIVE_FLOOR, fitted: list[ChannelFit] | None = None) -> list[np.ndarray]:
    """Each layer's two-sigma region in xy ((K, 2) each) from the channels' profile-likelihood
    intervals (:func:`.fit.fit_channels`, :func:`.layer_colour.layer_colours`) when ``forward``'s
    model is exact (:class:`ExactForward`): ``measured`` and ``error`` (R, C), relative ``floor``.
    ``fitted``, the channels' fits of these data with ``forward`` itself, guide these fits
    (:func:`.fit.fit_channel`): their first passes (:attr:`.fit.ChannelFit.data_minima`: weighted
    by the data's noise alone, those are the exact model's fits too), so the start grid is not
    searched again, and their intervals' ends and valleys, near which these intervals' ends lie
    (the weights differ only by the white run's variance)."""
    fits = fit_channels(ExactForward(forward), measured, error, floor=floor, guides=fitted)
    return [layer.region for layer in layer_colours(fits, forward.structure, forward.database.optics, colorspace)]


class DataLimit(NamedTuple):
    """What the data allow a layer: the width of its region when the model is exact (the larger
    extent in x or y of the profile-likelihood box of :func:`exact_regions` joined with
    ``ellipse``; the Fisher ellipse's :func:`allowed_width` alone where no box is given, infinite
    where that is), and the two-sigma Fisher ellipse in xy ((K, 2), around the layer's colour
    ``xy``) where the quadratic approximation holds (every channel's Fisher standard deviation of
    ``log mua`` at most :data:`.layer_colour.QUADRATIC_SPREAD`), else empty."""

    width: float
    ellipse: np.ndarray


def data_limits(forward: Forward, mua: np.ndarray, measured: np.ndarray, error: np.ndarray, used: np.ndarray,
                colorspace: str, correlation: float = 0.0, floor: float = RELATIVE_FLOOR,
                data_covariance: np.ndarray | None = None, xy: np.ndarray | None = None,
                boxes: list[np.ndarray] | None = None) -> list[DataLimit]:
    """Each layer's :class:`DataLimit` at the fit ``mua`` (C, L) of ``forward``'s structure, the
    data's noise as :func:`log_absorption_covariance` takes it (the joint fit's floor correlation);
    ``xy`` (L, 2), the layers' colours, centres the ellipses (none without); ``boxes``, each
    layer's :func:`exact_regions` (the Fisher width alone without)."""
    covariance = log_absorption_covariance(forward, mua, measured, error, used, correlation, floor, data_covariance)
    channels, layers = mua.shape
    optics = forward.database.optics
    limits = []
    for k in range(layers):
        index = np.arange(channels) * layers + k
        block = covariance[np.ix_(index, index)]
        mus = float(optics.mus[forward.structure.starts[k]])
        ellipse = np.zeros((0, 2))
        if (xy is not None and np.all(np.isfinite(block)) and np.all(np.isfinite(mua[:, k]))
                and np.all(np.sqrt(np.diagonal(block)) <= QUADRATIC_SPREAD)):
            ellipse = chromaticity_ellipse(xy[k], chromaticity_gradient(mus, mua[:, k], optics, colorspace), block)
        width = allowed_width(block, mus, mua[:, k], optics, colorspace)
        if boxes is not None and math.isfinite(width) and len(boxes[k]):
            width = float(np.ptp(joined(boxes[k], ellipse), axis=0).max())
        limits.append(DataLimit(width, ellipse))
    return limits


def limit_reason(width: float) -> str:
    """Why a layer whose data allow ``width`` is not determined to :data:`TOLERANCE_XY` ("" when it
    may be)."""
    if width <= TOLERANCE_XY:
        return ""
    allowed = "no finite width" if not math.isfinite(width) else f"no narrower than {width:.3f}"
    return (f"the data allow {allowed} in xy (the fitted model taken as exact, at the data's noise), "
            f"so no fit of this profile places this layer within {TOLERANCE_XY:g}")
