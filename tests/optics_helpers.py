"""Helpers of the optical-property tests: impulse responses of the maps' own model per pixel
offset, and small homogeneous datasets made from them."""

from __future__ import annotations

import numpy as np
from ringlight.core.optics import radial
from ringlight.core.optics.synthetic import homogeneous_dataset
from ringlight.core.optics.table import model_profiles, ring_kernels

TEST_PHOTONS = 40_000
"""Photons of the tests' white runs (a few seconds; table noise about 1 % per ring)."""


def model_kernel(run: radial.RadialRun, mus: float, mua: float, half: int) -> np.ndarray:
    """(2 half + 1, 2 half + 1, 3) the model's response at every pixel offset from the lit pixel
    (coefficients per grid step): each offset as a one-member "ring"."""
    side = 2 * half + 1
    dy, dx = np.mgrid[-half:half + 1, -half:half + 1]
    key = np.stack([np.minimum(abs(dy), abs(dx)), np.maximum(abs(dy), abs(dx))], -1).reshape(-1, 2)
    classes, inverse = np.unique(key, axis=0, return_inverse=True)
    weights = np.zeros((len(classes), side, side))
    for index, (low, high) in enumerate(classes):
        weights[index, half + low, half + high] = 1.0
    kernels, step = ring_kernels(np.zeros(len(classes)), ring_weights=weights)
    values = model_profiles(run, kernels, step, np.array([mus]), np.array([mua / mus]))[0, 0]
    return np.repeat(values[inverse.ravel()].reshape(side, side)[..., None], 3, axis=2)


def model_dataset(run, mus, mua, size, max_radius, *, noise=None, seed=0, pitch_mm=None, scale=1.0):
    """A ``size`` x ``size`` homogeneous dataset of the model's response (times ``scale``), with
    relative ``noise`` (per distance, :func:`~ringlight.core.optics.synthetic.homogeneous_dataset`)."""
    kernel = model_kernel(run, mus, mua, int(np.ceil(max_radius))) * scale
    return homogeneous_dataset(kernel, size, size, max_radius=max_radius, member_noise=noise, seed=seed,
                               pitch_mm=pitch_mm, n=run.n, g=run.g)
