"""Sampling the Henyey-Greenstein phase function: the scattering step that the simulator's walk
and the layer inversion's white Monte Carlo share (its density is
:func:`ringlight.core.simulate.camera.henyey_greenstein`). Directions are ``(y, x, z)`` unit vectors."""

from __future__ import annotations

import math

import numba

from .streams import uniform


@numba.njit(cache=True, inline="always")
def scatter_direction(state, uy, ux, uz, g):
    """The direction ``(uy, ux, uz)`` after a Henyey-Greenstein scattering of anisotropy ``g``,
    from two uniforms of ``state`` (the polar angle's, then the azimuth's)."""
    if g == 0.0:
        cos_theta = 2.0 * uniform(state) - 1.0
    else:
        ratio = (1.0 - g * g) / (1.0 - g + 2.0 * g * uniform(state))
        cos_theta = min(1.0, max(-1.0, (1.0 + g * g - ratio * ratio) / (2.0 * g)))
    sin_theta = math.sqrt(1.0 - cos_theta * cos_theta)
    phi = 2.0 * math.pi * uniform(state)
    cos_phi = math.cos(phi)
    sin_phi = math.sin(phi)
    if abs(uz) > 0.99999:
        return sin_theta * sin_phi, sin_theta * cos_phi, (cos_theta if uz > 0.0 else -cos_theta)
    root = math.sqrt(1.0 - uz * uz)
    new_ux = sin_theta * (ux * uz * cos_phi - uy * sin_phi) / root + ux * cos_theta
    new_uy = sin_theta * (uy * uz * cos_phi + ux * sin_phi) / root + uy * cos_theta
    return new_uy, new_ux, -sin_theta * cos_phi * root + uz * cos_theta
