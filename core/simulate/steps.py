"""The photon walk's steps, written once for both devices: the random stream's next uniform, the
surface crossing (Fresnel reflectance, the flight that reaches the surface), the
Henyey-Greenstein phase function and its sampling.

The functions here are plain Python; :func:`compile_steps` compiles them with a numba decorator:
``numba.njit`` for the CPU kernels (:data:`CPU`, which :mod:`.streams`, :mod:`.camera` and
:mod:`.phase` hand on) and ``numba.cuda.jit(device=True)`` for the CUDA kernels
(:func:`cuda_steps`), so that the two devices run the same statement of the physics and the same
random numbers on the same stream. Directions are ``(y, x, z)`` unit vectors, ``z`` down into the
medium; depths and lengths in grid steps.
"""

from __future__ import annotations

import functools
import math
from typing import Callable, NamedTuple

import numba
import numpy as np


def rotate_left(x, k):
    """``x`` (uint64) rotated left by ``k`` bits."""
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


def splitmix(value):
    """``(next value, output)`` of splitmix64 from the uint64 ``value``: the seeding of a stream."""
    value = value + np.uint64(0x9E3779B97F4A7C15)
    z = value
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return value, z ^ (z >> np.uint64(31))


def exit_fresnel(n, cos_inside):
    """Unpolarised Fresnel reflectance between a medium of index n and air, for the angle
    ``arccos(cos_inside)`` inside (1.0 at total internal reflection). The same either way
    across the surface: light from air at the matching outside angle reflects as much."""
    if n == 1.0:
        return 0.0
    sin_inside = math.sqrt(max(0.0, 1.0 - cos_inside * cos_inside))
    sin_out = n * sin_inside
    if sin_out >= 1.0:
        return 1.0
    cos_out = math.sqrt(1.0 - sin_out * sin_out)
    rs = (n * cos_inside - cos_out) / (n * cos_inside + cos_out)
    rp = (cos_inside - n * cos_out) / (cos_inside + n * cos_out)
    return 0.5 * (rs * rs + rp * rp)


def henyey_greenstein(cos_angle, g):
    """Henyey-Greenstein phase function per steradian."""
    if g == 0.0:
        return 0.25 / math.pi
    denominator = 1.0 + g * g - 2.0 * g * cos_angle
    return (1.0 - g * g) / (4.0 * math.pi * denominator * math.sqrt(denominator))


def flight_to_surface(z, uz, step):
    """The length of the flight from depth ``z`` along ``uz`` to the surface ``z = 0`` when a
    flight of ``step`` reaches it; -1.0 when it does not."""
    if uz < 0.0 and z + step * uz <= 0.0:
        return -z / uz
    return -1.0


def scattered_direction(uy, ux, uz, g, polar, azimuth):
    """The direction ``(uy, ux, uz)`` after a Henyey-Greenstein scattering of anisotropy ``g``,
    from two uniforms in [0, 1): ``polar`` for the polar angle, ``azimuth`` for the azimuth."""
    if g == 0.0:
        cos_theta = 2.0 * polar - 1.0
    else:
        ratio = (1.0 - g * g) / (1.0 - g + 2.0 * g * polar)
        cos_theta = min(1.0, max(-1.0, (1.0 + g * g - ratio * ratio) / (2.0 * g)))
    sin_theta = math.sqrt(1.0 - cos_theta * cos_theta)
    phi = 2.0 * math.pi * azimuth
    cos_phi = math.cos(phi)
    sin_phi = math.sin(phi)
    if abs(uz) > 0.99999:
        return sin_theta * sin_phi, sin_theta * cos_phi, (cos_theta if uz > 0.0 else -cos_theta)
    root = math.sqrt(1.0 - uz * uz)
    new_ux = sin_theta * (ux * uz * cos_phi - uy * sin_phi) / root + ux * cos_theta
    new_uy = sin_theta * (uy * uz * cos_phi + ux * sin_phi) / root + uy * cos_theta
    return new_uy, new_ux, -sin_theta * cos_phi * root + uz * cos_theta


class Steps(NamedTuple):
    """The steps compiled for one device (each as the plain function of the same name documents;
    ``next_raw(state)`` advances a xoroshiro128+ state of 2 uint64 in place and returns its next
    uint64, ``uniform(state)`` the same step as a float in [0, 1) (its top 53 bits),
    ``seed_from(value, state)`` seeds ``state`` in place from the uint64 ``value`` by splitmix64,
    ``fresh_state(seeder, state)`` reseeds ``state`` in place from the next output of ``seeder``
    (advanced): independent streams one after another, for walks that must be replayed from their
    start; ``scatter(state, uy, ux, uz, g)`` draws the polar uniform, then the
    azimuth's, ``camera_constant(n)`` is ``T_entry pi T_F(0) / n^2``: the Fresnel transmission of
    a beam entering straight down times the view factor of a camera straight above)."""

    rotate_left: Callable
    next_raw: Callable
    seed_from: Callable
    fresh_state: Callable
    uniform: Callable
    exit_fresnel: Callable
    henyey_greenstein: Callable
    flight_to_surface: Callable
    scattered_direction: Callable
    scatter: Callable
    camera_constant: Callable


def compile_steps(jit) -> Steps:
    """The steps compiled with ``jit`` (a decorator such as ``numba.njit(inline="always")`` or
    ``numba.cuda.jit(device=True)``); the two that compose others call the compiled ones."""
    rotate = jit(rotate_left)
    direction = jit(scattered_direction)

    def next_raw(state):
        s0 = state[0]
        s1 = state[1]
        result = s0 + s1
        s1 ^= s0
        state[0] = rotate(s0, 24) ^ s1 ^ (s1 << np.uint64(16))
        state[1] = rotate(s1, 37)
        return result

    raw = jit(next_raw)
    mix = jit(splitmix)

    def seed_from(value, state):
        value, state[0] = mix(value)
        value, state[1] = mix(value)
        if state[0] == 0 and state[1] == 0:
            state[0] = np.uint64(1)

    seed = jit(seed_from)

    def fresh_state(seeder, state):
        seed(raw(seeder), state)

    def uniform(state):
        return (raw(state) >> np.uint64(11)) * (1.0 / 9007199254740992.0)

    next_uniform = jit(uniform)

    def scatter(state, uy, ux, uz, g):
        return direction(uy, ux, uz, g, next_uniform(state), next_uniform(state))

    fresnel = jit(exit_fresnel)

    def camera_constant(n):
        return (1.0 - fresnel(n, 1.0)) * (math.pi * (1.0 - fresnel(n, 1.0)) / (n * n))

    return Steps(rotate, raw, seed, jit(fresh_state), next_uniform, fresnel, jit(henyey_greenstein),
                 jit(flight_to_surface), direction,
                 jit(scatter), jit(camera_constant))


CPU = compile_steps(numba.njit(cache=True, inline="always"))
"""The steps for the CPU kernels."""


@functools.cache
def cuda_steps() -> Steps:
    """The steps for the CUDA kernels (numba.cuda imported on first use: only a CUDA run needs it)."""
    from numba import cuda

    return compile_steps(cuda.jit(device=True))
