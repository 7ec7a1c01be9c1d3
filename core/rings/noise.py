"""Standard errors of ring light and transient images from the spread of each ring's members.

E_r(p) is the weighted mean of its ring members x_q = I_q(p) with weights w_q (1, or the pixel's
area inside the annulus for anti-aliased rings). Members at the same distance ``|q - p|`` share one
expected value on a homogeneous surface, while across the ring's thickness the radial fall-off
changes it (at r = 1 the members at distances 1 and 1.41 differ by far more than their noise),
so the spread is pooled within the groups g of equal distance::

    s_w^2 = sum_g sum_{q in g} w (x - xbar_g)^2 / sum_g (V1_g - V2_g / V1_g)

(V1 = sum w, V2 = sum w^2; unbiased for independent members of equal variance, and for one
group of unit weights the familiar sample variance, ddof 1). With Kish's effective sample size
n_eff = V1^2 / V2 of the whole ring, the standard error of the weighted mean is::

    SE(E_r)^2 = s_w^2 / n_eff

undefined (NaN) when no distance group has 2 members (fewer than 2 members, e.g. r = 0).

T_r = E_r - E_{r+dr} (paper Eq. 8) subtracts two rings without a common member when
dr >= thickness, so SE(T_r)^2 = SE(E_r)^2 + SE(E_{r+dr})^2. Rings that share members (dr <
thickness, or the edge pixels of anti-aliased rings) covary positively, so there the sum is an
upper bound.

The spread of the members is noise only on a homogeneous surface: it also holds real spatial
variation (a heterogeneous surface, an oblique view), so on such a surface these standard
errors are an upper bound of the noise. Members are taken as independent: each is a different
lit point, measured in a different frame. Noise the lit points share (a simulator's kernel common
to every point, a projector's flicker) does not show in their spread: a dataset that holds
independent replicates of its capture gets its standard errors from them (:mod:`.replicate_noise`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from ..colourspaces import colourspace_luminance as luminance_weights
from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback
from ..errors import StackError
from .replicate_noise import replicate_spread
from .radii import RADIUS_DECIMALS
from .stacks import ring_weight_matrix



@dataclass(frozen=True, eq=False)
class StackNoise:
    """Standard errors of a request's E_r and T_r = E_r - E_{r+step}, from the ring spread.

    Attributes
    ----------
    radii
        (n,) ring radii in grid steps.
    step
        dr in grid steps.
    ring, transient
        (n, H, W, 3) float32 standard error of E_r and of T_r per channel (linear radiance, as
        the images); NaN where a ring has fewer than 2 members.
    ring_luminance, transient_luminance
        (n, H, W) float32 standard error of the relative luminance Y of E_r and of T_r
        (Y = the colourspace's RGB -> XYZ row, as in ``ringlight.core.colour.chroma``).
    luminance_weights
        (3,) float64 that Y row.
    """

    radii: np.ndarray
    step: float
    ring: np.ndarray
    transient: np.ndarray
    ring_luminance: np.ndarray
    transient_luminance: np.ndarray
    luminance_weights: np.ndarray


def stack_noise(dataset: ImpulseDataset, radii, step: float = 1.0, thickness: float = 1.0,
                antialias: bool = False, progress: ProgressCallback | None = None) -> StackNoise:
    """Standard errors of E_r and T_r = E_r - E_{r+step} for each radius (grid steps) of ``radii``.

    A dataset of two or more replicates (:attr:`~ringlight.core.dataset.manifest.Manifest.replicates`)
    gets them from the replicates' spread instead (:mod:`.replicate_noise`), which holds noise its
    lit points share. Otherwise: uses the rings of :func:`ringlight.core.rings.stacks.transient_stack`
    with the same arguments; each distinct ring is measured once, by one compiled kernel over the responses and
    each band's validity flags (``benchmarks/bench_stack.py``: 72-91 ms, 4.5-4.8x the stack, which
    counts members from the lit mask instead of reading flags). ``progress`` may raise
    ``Cancelled``.
    """
    radii = np.round(np.atleast_1d(np.asarray(radii, np.float64)), RADIUS_DECIMALS)
    if not math.isfinite(step) or step <= 0:
        raise StackError(f"transient step dr must be > 0, got {step}")
    outer = np.round(radii + step, RADIUS_DECIMALS)
    unique = np.unique(np.concatenate([radii, outer]))
    luma = luminance_weights(dataset.colorspace)
    inner, outer = np.searchsorted(unique, radii), np.searchsorted(unique, outer)
    if len(dataset.manifest.replicates) > 1:
        ring, transient, ring_y, transient_y = replicate_spread(dataset, unique, inner, outer, thickness, antialias,
                                                                luma, progress)
        return StackNoise(radii, float(step), ring, transient, ring_y, transient_y, luma)
    se, se_luminance = _ring_spread(dataset, unique, thickness, antialias, luma, progress)
    return StackNoise(
        radii, float(step), se[inner], np.sqrt(se[inner] ** 2 + se[outer] ** 2),
        se_luminance[inner], np.sqrt(se_luminance[inner] ** 2 + se_luminance[outer] ** 2), luma,
    )


def transient_snr(transient_images: np.ndarray, noise: StackNoise) -> np.ndarray:
    """(n, H, W) float32 signal-to-noise ratio ``|Y(T_r)| / SE(Y(T_r))`` of (n, H, W, 3) transient
    images; NaN where T_r or its standard error is undefined, inf where the error is 0."""
    luminance = np.abs(transient_images @ noise.luminance_weights.astype(np.float32))
    with np.errstate(invalid="ignore", divide="ignore"):
        return (luminance / noise.transient_luminance).astype(np.float32)


def median_snr(snr: np.ndarray, region: np.ndarray | None = None) -> np.ndarray:
    """(n,) float64 median over the (H, W) bool ``region`` (default: all pixels) of each
    (n, H, W) ``snr`` image, over its defined pixels; NaN where none is defined.

    Examples
    --------
    >>> median_snr(np.array([[[1.0, np.nan], [3.0, 8.0]]])).tolist()
    [3.0]
    """
    values = snr.reshape(len(snr), -1) if region is None else snr[:, np.asarray(region, bool)]
    medians = np.full(len(snr), np.nan)
    for index, row in enumerate(values):
        row = row[~np.isnan(row)]
        if len(row):
            medians[index] = np.median(row)
    return medians


def region_snr(transient_images: np.ndarray, noise: StackNoise, region: np.ndarray) -> np.ndarray:
    """(n,) float64 signed SNR of the region-mean luminance of each transient image.

    The mean runs over the pixels of the (H, W) bool ``region`` where T_r is defined (m of
    them); its standard error is sqrt(mean SE(Y)^2 / m), the mean squared error taken over the
    pixels whose error is defined (pixels taken as independent: each has its own measurements
    I_q(p), seen by its own camera pixel). NaN where no
    pixel is defined.
    """
    region = np.asarray(region, bool)
    luminance = transient_images[:, region].astype(np.float64) @ noise.luminance_weights  # (n, m)
    variance = noise.transient_luminance[:, region].astype(np.float64) ** 2
    defined = np.isfinite(luminance)
    pixels = defined.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(defined, luminance, 0.0).sum(axis=1) / pixels
        known = defined & np.isfinite(variance)
        mean_variance = np.where(known, variance, 0.0).sum(axis=1) / known.sum(axis=1)
        snr = mean / np.sqrt(mean_variance / pixels)
    snr[(pixels == 0) | ~np.isfinite(mean_variance)] = np.nan
    return snr


def smoothed(image: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian blur of standard deviation ``sigma`` (grid steps) of an (H, W) or (H, W, C)
    image, for display: NaN pixels stay NaN and neither they nor the grid's outside contribute
    (normalised convolution). Returns float32 of the same shape.

    Examples
    --------
    >>> smoothed(np.array([[1.0, np.nan, 3.0]]), 1.0).astype(np.float64).round(3).tolist()
    [[1.238, nan, 2.762]]
    """
    image = np.asarray(image, np.float32)
    defined = np.isfinite(image)
    # OpenCV blurs up to 4 channels of float32: weight and value both, with zero outside the grid.
    weight = cv2.GaussianBlur(defined.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    value = cv2.GaussianBlur(np.where(defined, image, 0.0).astype(np.float32), (0, 0), sigma,
                             borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        result = (value / weight).reshape(image.shape)
    result[~defined] = np.nan
    return result


def _ring_runs(dataset: ImpulseDataset, radii: np.ndarray, thickness: float, antialias: bool):
    """Each ring as a run ``[first, stop)`` of the dataset's offset axis with its weights, from
    the stacks' :func:`ring_weight_matrix` (offsets are sorted by distance, so rings are runs)."""
    matrix = ring_weight_matrix(dataset, radii, thickness, antialias)
    first, stop, weight_start, weights = [], [], [0], []
    for row in matrix:
        members = np.flatnonzero(row)
        low, high = (int(members[0]), int(members[-1]) + 1) if len(members) else (0, 0)
        first.append(low)
        stop.append(high)
        weights.append(row[low:high])
        weight_start.append(weight_start[-1] + high - low)
    return (np.asarray(first, np.int64), np.asarray(stop, np.int64),
            np.asarray(weight_start, np.int64), np.concatenate(weights))


def _distance_groups(offsets: np.ndarray) -> np.ndarray:
    """(K,) int64: for each offset, one past the last of the run of offsets at its distance
    (the offset axis is sorted by distance, so members at one distance are consecutive)."""
    squared = (offsets.astype(np.int64) ** 2).sum(axis=1)
    ends = np.flatnonzero(np.diff(squared)) + 1
    return np.append(ends, len(squared))[np.searchsorted(ends, np.arange(len(squared)), side="right")]


def _ring_spread(dataset, radii, thickness, antialias, luma, progress):
    first, stop, weight_start, weights = _ring_runs(dataset, radii, thickness, antialias)
    group_end = _distance_groups(dataset.offsets)
    height, width = dataset.grid_shape
    se = np.empty((len(radii), height, width, 3), np.float32)
    se_luminance = np.empty((len(radii), height, width), np.float32)
    for row0, row1 in dataset.bands():
        _spread_kernel(dataset.rows(row0, row1), dataset.validity_rows(row0, row1), first, stop, weight_start,
                       weights, group_end, luma, row0, se, se_luminance)
        if progress is not None:
            progress(row1 / height)
    return se, se_luminance


@numba.njit(parallel=True, cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _spread_kernel(responses, validity, first, stop, weight_start, weights, group_end, luma, row0, se,
                   se_luminance):
    """Standard error of each ring's weighted mean (module docstring) of the band of grid rows from
    ``row0`` (``responses`` and ``validity`` hold the band's rows), into the whole grid's ``se``
    (n, H, W, 3) and ``se_luminance`` (n, H, W) at rows ``row0 + y``: whole arrays, so that the
    kernel is compiled for one layout (a band's slice of them was contiguous when one band covered
    the grid and strided otherwise: two compiles of 9-17 s).

    Per distance group: its weighted mean, then the weighted squared deviations from it (two
    passes over a few cached members, no cancellation as in sum x^2 - n mean^2).
    """
    rows, width = validity.shape[0], validity.shape[1]
    for y in numba.prange(rows):
        row = row0 + y
        for x in range(width):
            pixel = responses[y, x]
            valid = validity[y, x]
            for j in range(first.size):
                shift = weight_start[j] - first[j]
                v1 = 0.0
                v2 = 0.0
                dof = 0.0
                pairs = 0
                q0 = 0.0
                q1 = 0.0
                q2 = 0.0
                qy = 0.0
                start = first[j]
                while start < stop[j]:
                    end = min(group_end[start], stop[j])
                    s0 = 0.0
                    s1 = 0.0
                    s2 = 0.0
                    g1 = 0.0
                    g2 = 0.0
                    count = 0
                    for k in range(start, end):
                        w = weights[shift + k] * valid[k]
                        s0 += w * pixel[k, 0]
                        s1 += w * pixel[k, 1]
                        s2 += w * pixel[k, 2]
                        g1 += w
                        g2 += w * w
                        count += valid[k] * (weights[shift + k] > 0.0)
                    if count >= 2:
                        m0, m1, m2 = s0 / g1, s1 / g1, s2 / g1
                        for k in range(start, end):
                            w = weights[shift + k] * valid[k]
                            d0 = pixel[k, 0] - m0
                            d1 = pixel[k, 1] - m1
                            d2 = pixel[k, 2] - m2
                            dy = luma[0] * d0 + luma[1] * d1 + luma[2] * d2
                            q0 += w * d0 * d0
                            q1 += w * d1 * d1
                            q2 += w * d2 * d2
                            qy += w * dy * dy
                        dof += g1 - g2 / g1
                        pairs += 1
                    v1 += g1
                    v2 += g2
                    start = end
                if pairs == 0:
                    se[j, row, x, 0] = np.nan
                    se[j, row, x, 1] = np.nan
                    se[j, row, x, 2] = np.nan
                    se_luminance[j, row, x] = np.nan
                    continue
                # SE^2 = s_w^2 / n_eff = (sum_g sum w d^2 / sum_g (V1_g - V2_g / V1_g)) * V2 / V1^2
                factor = v2 / (dof * v1 * v1)
                se[j, row, x, 0] = math.sqrt(q0 * factor)
                se[j, row, x, 1] = math.sqrt(q1 * factor)
                se[j, row, x, 2] = math.sqrt(q2 * factor)
                se_luminance[j, row, x] = math.sqrt(qy * factor)
