"""Diffuse reflectance at spatial frequencies from a ring profile: the Hankel transform that makes
an impulse scan comparable with spatial frequency domain imaging (SFDI).

A pixel's impulse response ``I(d)`` over pixel offsets ``d`` is its spatially resolved
reflectance; lit by a sinusoid of frequency ``f`` (cycles per grid step) at every azimuth, its
modulated reflectance is the continuous transform ``R_d(f) = 2 pi int E(r) J0(2 pi f r) r dr``,
here summed over the pixels, as the data hold it::

    R_d(f) = sum_d I(d) J0(2 pi f |d|) ~= sum_r E(r) sum_{d in ring r} w_d J0(2 pi f |d|) / mean(w)

The rings of radius 0, 1, 2, ... (thickness 1) tile the disc of the last ring's outer radius
``R = r_last + 1/2`` without overlap, and E(r) is the ring's mean, so the sum is exact where the
response is the same on all members of a ring (a laterally homogeneous surface) and otherwise
the ring's members carry its mean. Light beyond ``R`` is not in the data (the dataset's
max_radius cuts it off): :func:`diffuse_reflectance` is the transform of what the rings hold;
:func:`model_tail` gives a fitted homogeneous medium's share beyond ``R``, which
:mod:`.region` adds, so that R_d compares with an SFDI instrument's (which sees all the light). The tail is counted
from the circle of radius ``R`` while the rings end on pixel squares: their sum at ``f = 0`` is
exact to about 0.5 % (``tests/test_optics_transform.py``). Inside the rings the data hold pixels
(the beam's square, the camera's), whose transfer lowers R_d against a continuous pattern's by
about 1.5 % at 0.05 to 0.1 cycles per grid step.

The quantity is the data's: for a simulated dataset the reflectance factor toward a camera
straight down (docs/format/scene.md), for a calibrated rig that times the calibration's scale. At
``f = 0`` it is the response's sum: the total diffuse reflectance where the surface sends light
out as a Lambertian one would (and exactly so for a dataset simulated with ``measure: exitance``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import j0

from ..rings.geometry import ring_geometry
from .radial import RadialRun


def ring_transform_weights(radii, frequencies, thickness: float = 1.0, antialias: bool = False) -> np.ndarray:
    """(F, R) float64: ``sum_{d in ring r} w_d J0(2 pi f |d|) / mean(w)`` for each frequency ``f``
    (cycles per grid step) and ring; at ``f = 0`` each ring's member count (its area)."""
    frequencies = np.atleast_1d(np.asarray(frequencies, np.float64))
    out = np.zeros((len(frequencies), len(radii)))
    for column, radius in enumerate(np.asarray(radii, np.float64)):
        ring = ring_geometry(float(radius), thickness, antialias)
        if len(ring.offsets) == 0:
            continue
        distance = np.hypot(ring.offsets[:, 0], ring.offsets[:, 1])
        weights = ring.weights / ring.weights.mean()
        out[:, column] = j0(2.0 * math.pi * frequencies[:, None] * distance[None, :]) @ weights
    return out


def diffuse_reflectance(profile_radii, profile_values, frequencies, *, thickness: float = 1.0,
                        antialias: bool = False) -> np.ndarray:
    """R_d at ``frequencies`` (cycles per grid step) of a ring profile.

    Parameters
    ----------
    profile_radii
        (R,) ring radii, grid steps: 0, 1, 2, ... so that the rings tile a disc (thickness 1).
    profile_values
        (R,) or (R, ...) E(r) per ring (a pixel's profile, a region's mean, a stack (R, H, W, 3)).
    frequencies
        (F,) spatial frequencies, cycles per grid step (divide cycles per mm by ``pitch_mm``'s
        inverse: ``f_step = f_mm * pitch_mm``).

    Returns
    -------
    np.ndarray
        (F, ...) float64: the transform of the light within the last ring (module docstring); NaN
        where a ring's value is NaN.

    Examples
    --------
    >>> import numpy as np
    >>> diffuse_reflectance([0, 1, 2], [1.0, 0.1, 0.01], [0.0]).round(4).tolist()   # 1 + 8 * 0.1 + 12 * 0.01
    [1.92]
    """
    radii = np.asarray(profile_radii, np.float64)
    values = np.asarray(profile_values, np.float64)
    if values.shape[0] != len(radii):
        raise ValueError(f"{len(radii)} radii but {values.shape[0]} profile values")
    weights = ring_transform_weights(radii, frequencies, thickness, antialias)
    return np.tensordot(weights, values, axes=(1, 0))


def model_tail(run: RadialRun, mus: float, mua: float, frequencies, beyond: float) -> np.ndarray:
    """(F,) R_d of a homogeneous half-space (``mus``, ``mua`` per grid step, the run's n and g)
    from the light that leaves farther than ``beyond`` grid steps from the lit pixel: the share
    the rings up to ``beyond`` do not hold. The pixel's size is neglected there (the tail starts
    several pixels out)."""
    frequencies = np.atleast_1d(np.asarray(frequencies, np.float64))
    distance = run.rho / mus
    far = (distance > beyond) & (run.weight > 0)
    weight = run.weight[far] * np.exp(-(mua / mus) * run.path[far])
    return j0(2.0 * math.pi * frequencies[:, None] * distance[far][None, :]) @ weight / run.photons


def tail_table(run: RadialRun, u: np.ndarray, v: np.ndarray, frequencies, beyond: float) -> np.ndarray:
    """(F, K, J) :func:`model_tail` at every node of a table's grid, ``mus = e^u_k`` and
    ``mua / mus = e^v_j`` (per grid step), for ``frequencies`` (cycles per grid step)."""
    frequencies = np.atleast_1d(np.asarray(frequencies, np.float64))
    used = run.weight.sum(axis=1) > 0
    weight, path = run.weight[used], run.path[used]
    rho = (weight * run.rho[used]).sum(axis=1) / weight.sum(axis=1)  # each rho cell's mean distance
    absorbed = np.stack([(weight * np.exp(-ratio * path)).sum(axis=1) for ratio in np.exp(v)])  # (J, I)
    out = np.empty((len(frequencies), len(u), len(v)))
    for k, mus in enumerate(np.exp(u)):
        distance = rho / mus
        far = distance > beyond
        waves = j0(2.0 * math.pi * frequencies[:, None] * distance[None, far])  # (F, I')
        out[:, k] = waves @ absorbed[:, far].T / run.photons
    return out


def reflectance_maps(maps, images: np.ndarray, frequencies, *, photons: int | None = None) -> np.ndarray:
    """R_d per pixel and channel at ``frequencies``: each pixel's rings transformed
    (:func:`diffuse_reflectance`) plus its fitted medium's light beyond them (:func:`model_tail`,
    interpolated bilinearly in the table's grid of log mus and log mua / mus: R_d within 0.5 % of
    the direct sum).

    Parameters
    ----------
    maps
        :class:`.maps.OpticalMaps` fitted to ``images``.
    images
        (R, H, W, 3) the ring stack at ``maps.radii`` (thickness 1) the maps were fitted to.
    frequencies
        (F,) cycles per mm when ``maps.units`` is ``"per_mm"``, else per grid step.
    photons
        The table's white run (default: :data:`.table.DEFAULT_PHOTONS`, as the maps').

    Returns
    -------
    np.ndarray
        (F, H, W, 3) float32; the tail is NaN (and so R_d) where the fit is (no fit, or outside
        the table).
    """
    from .table import DEFAULT_PHOTONS, table_for

    frequencies = np.atleast_1d(np.asarray(frequencies, np.float64))
    pitch = maps.pitch_mm if maps.units == "per_mm" else None
    per_step = frequencies * pitch if pitch else frequencies
    out = diffuse_reflectance(maps.radii, images, per_step)
    table = table_for(maps.n, maps.g, maps.radii, photons=DEFAULT_PHOTONS if photons is None else photons)
    u = table.u0 + table.du * np.arange(table.log_profile.shape[0])
    v = table.v0 + table.dv * np.arange(table.log_profile.shape[1])
    tails = tail_table(table.run, u, v, per_step, float(maps.radii[-1]) + 0.5)
    step = pitch if pitch else 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        mus = maps.musp.astype(np.float64) * step / (1.0 - maps.g)
        ku = (np.log(mus) - table.u0) / table.du
        kv = (np.log(maps.mua.astype(np.float64) * step / mus) - table.v0) / table.dv
    inside = np.isfinite(ku) & np.isfinite(kv) & (ku >= 0) & (kv >= 0) & (ku <= len(u) - 1) & (kv <= len(v) - 1)
    k0 = np.clip(np.floor(np.where(inside, ku, 0)).astype(int), 0, len(u) - 2)
    j0_ = np.clip(np.floor(np.where(inside, kv, 0)).astype(int), 0, len(v) - 2)
    tu, tv = np.where(inside, ku, 0) - k0, np.where(inside, kv, 0) - j0_
    for index in range(len(frequencies)):
        grid = tails[index]
        tail = ((1 - tu) * (1 - tv) * grid[k0, j0_] + tu * (1 - tv) * grid[k0 + 1, j0_]
                + (1 - tu) * tv * grid[k0, j0_ + 1] + tu * tv * grid[k0 + 1, j0_ + 1])
        out[index] += np.where(inside, tail * maps.scale[None, None, :], np.nan)
    return out.astype(np.float32)
