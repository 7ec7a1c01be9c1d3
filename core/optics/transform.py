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
