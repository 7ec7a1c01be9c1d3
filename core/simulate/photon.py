"""Compiled Monte Carlo photon transport in a voxel volume below a flat surface (numba).

Units: lengths in grid steps, coefficients per grid step. Depth ``z`` grows downward from the
surface ``z = 0``; lateral position ``(y, x)`` in grid coordinates (pixel centres on integers).
One photon (scalar weight, one colour channel) enters straight down at a given point:

- Fresnel at entry: the specular part ((n - 1) / (n + 1))^2 is the caller's to record; the
  photon continues with weight 1 - that.
- Free paths by delta (Woodcock) tracking against a majorant of mu_t, so heterogeneous voxels
  need no ray marching; a tentative collision is real with probability mu_t(voxel) / majorant.
- At a real collision the weight is multiplied by the albedo (implicit capture) and the photon
  scatters by Henyey-Greenstein; below weight 1e-4 Russian roulette keeps 1 in 10.
- At the surface, unpolarised Fresnel reflection with total internal reflection, sampled
  (reflect with probability R, else exit with the full weight); through ``z = depth`` it is lost.

Random numbers: xoroshiro128+ seeded by splitmix64 from ``(seed, stream)``, one stream per
lit point and channel, so results do not depend on the number of threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

ROULETTE_WEIGHT = 1e-4
ROULETTE_SURVIVAL = 0.1


@numba.njit(cache=True, inline="always")
def _rotl(x, k):
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


@numba.njit(cache=True)
def _splitmix(value):
    value = value + np.uint64(0x9E3779B97F4A7C15)
    z = value
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return value, z ^ (z >> np.uint64(31))


@numba.njit(cache=True)
def seed_state(seed, stream):
    """A fresh xoroshiro128+ state (2 uint64) for ``(seed, stream)``."""
    state = np.empty(2, np.uint64)
    value = np.uint64(seed) * np.uint64(0x100000001B3) ^ np.uint64(stream)
    value, state[0] = _splitmix(value)
    value, state[1] = _splitmix(value)
    if state[0] == 0 and state[1] == 0:
        state[0] = np.uint64(1)
    return state


@numba.njit(cache=True, inline="always")
def uniform(state):
    """Next float in [0, 1) from a xoroshiro128+ state (advanced in place)."""
    s0 = state[0]
    s1 = state[1]
    result = s0 + s1
    s1 ^= s0
    state[0] = _rotl(s0, 24) ^ s1 ^ (s1 << np.uint64(16))
    state[1] = _rotl(s1, 37)
    return (result >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, inline="always")
def exit_fresnel(n, cos_inside):
    """Unpolarised reflectance for light leaving a medium of index n into air (1.0 at TIR)."""
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


def specular_reflectance(n: float) -> float:
    """Fresnel reflectance at normal incidence from air, ((n - 1) / (n + 1))^2."""
    return ((n - 1.0) / (n + 1.0)) ** 2


@numba.njit(cache=True)
def trace_photon(state, y, x, volume, mu_t, albedo, g, majorant, n, depth):
    """Trace one photon entering at ``(y, x)``. Returns ``(exited, exit_y, exit_x, length,
    weight)``: whether it left through the surface, where, its path length inside, and its
    weight (relative to the weight after the entry's specular loss)."""
    layers, height, width = volume.shape
    z = 0.0
    uy = 0.0
    ux = 0.0
    uz = 1.0
    weight = 1.0
    length = 0.0
    while True:
        step = -math.log(1.0 - uniform(state)) / majorant
        if uz < 0.0 and z + step * uz <= 0.0:
            travel = -z / uz
            y += travel * uy
            x += travel * ux
            length += travel
            z = 0.0
            if uniform(state) < exit_fresnel(n, -uz):
                uz = -uz
                continue
            return True, y, x, length, weight
        if uz > 0.0 and z + step * uz >= depth:
            return False, y, x, length, weight
        y += step * uy
        x += step * ux
        z += step * uz
        length += step
        iz = min(int(z), layers - 1)
        iy = min(max(int(math.floor(y + 0.5)), 0), height - 1)
        ix = min(max(int(math.floor(x + 0.5)), 0), width - 1)
        material = volume[iz, iy, ix]
        if uniform(state) * majorant >= mu_t[material]:
            continue  # null collision: the majorant's fictitious particles
        weight *= albedo[material]
        anisotropy = g[material]
        if anisotropy == 0.0:
            cos_theta = 2.0 * uniform(state) - 1.0
        else:
            ratio = (1.0 - anisotropy * anisotropy) / (1.0 - anisotropy + 2.0 * anisotropy * uniform(state))
            cos_theta = (1.0 + anisotropy * anisotropy - ratio * ratio) / (2.0 * anisotropy)
            cos_theta = min(1.0, max(-1.0, cos_theta))
        sin_theta = math.sqrt(1.0 - cos_theta * cos_theta)
        phi = 2.0 * math.pi * uniform(state)
        cos_phi = math.cos(phi)
        sin_phi = math.sin(phi)
        if abs(uz) > 0.99999:
            uy = sin_theta * sin_phi
            ux = sin_theta * cos_phi
            uz = cos_theta if uz > 0.0 else -cos_theta
        else:
            root = math.sqrt(1.0 - uz * uz)
            new_ux = sin_theta * (ux * uz * cos_phi - uy * sin_phi) / root + ux * cos_theta
            new_uy = sin_theta * (uy * uz * cos_phi + ux * sin_phi) / root + uy * cos_theta
            uz = -sin_theta * cos_phi * root + uz * cos_theta
            ux = new_ux
            uy = new_uy
        if weight < ROULETTE_WEIGHT:
            if uniform(state) < ROULETTE_SURVIVAL:
                weight /= ROULETTE_SURVIVAL
            else:
                return False, y, x, length, 0.0


@numba.njit(cache=True, nogil=True)
def reflectance_run(volume, mu_t, albedo, g, majorant, n, depth, photons, seed, stream):
    """Trace ``photons`` entering at the origin; returns ``(sum of exit weights, sum of their
    squares)`` per photon (a photon that is lost counts 0), for mean and standard error."""
    state = seed_state(seed, stream)
    total = 0.0
    total_sq = 0.0
    for _ in range(photons):
        exited, _, _, _, weight = trace_photon(state, uniform(state) - 0.5, uniform(state) - 0.5,
                                               volume, mu_t, albedo, g, majorant, n, depth)
        if exited:
            total += weight
            total_sq += weight * weight
    return total, total_sq


@numba.njit(cache=True, nogil=True)
def trace_exits(volume, mu_t, albedo, g, majorant, n, depth, y, x, photons, seed, stream):
    """Exit records of ``photons`` entering pixel ``(y, x)``: (photons, 5) float64 rows of
    ``[exited, entry_y, entry_x, exit_y, exit_x, length, weight]`` (for tests and inspection)."""
    state = seed_state(seed, stream)
    records = np.zeros((photons, 7))
    for i in range(photons):
        entry_y = y + uniform(state) - 0.5
        entry_x = x + uniform(state) - 0.5
        exited, exit_y, exit_x, length, weight = trace_photon(
            state, entry_y, entry_x, volume, mu_t, albedo, g, majorant, n, depth)
        records[i, 0] = 1.0 if exited else 0.0
        records[i, 1] = entry_y
        records[i, 2] = entry_x
        records[i, 3] = exit_y
        records[i, 4] = exit_x
        records[i, 5] = length
        records[i, 6] = weight
    return records


@numba.njit(parallel=True, cache=True, nogil=True)
def simulate_points(volume, mu_t, albedo, g, majorant, n, depth, lit, photons, seed, streams,
                    window_radius, bin_step, windows, truth):
    """Trace ``photons`` from each lit point ``lit[i] = [y, x]`` with random stream ``streams[i]``.

    ``windows`` (len(lit), 2R+1, 2R+1) float64 receives exit weights around each lit point
    (offset ``[dy + R, dx + R]``, R = window_radius); ``truth`` (blocks, bins, H, W) float64
    receives every exit inside the grid by path-length bin ``floor(length / bin_step)``, lit
    point ``i`` into block ``i * blocks // len(lit)``, so that summing blocks in order gives the
    same result whatever the number of threads. Weights are raw (not divided by photons).
    """
    count = lit.shape[0]
    blocks = truth.shape[0]
    bins = truth.shape[1]
    height = truth.shape[2]
    width = truth.shape[3]
    for block in numba.prange(blocks):
        for i in range(block * count // blocks, (block + 1) * count // blocks):
            state = seed_state(seed, streams[i])
            ly = lit[i, 0]
            lx = lit[i, 1]
            for _ in range(photons):
                exited, exit_y, exit_x, length, weight = trace_photon(
                    state, ly + uniform(state) - 0.5, lx + uniform(state) - 0.5,
                    volume, mu_t, albedo, g, majorant, n, depth)
                if not exited:
                    continue
                py = int(math.floor(exit_y + 0.5))
                px = int(math.floor(exit_x + 0.5))
                dy = py - ly
                dx = px - lx
                if abs(dy) <= window_radius and abs(dx) <= window_radius:
                    windows[i, dy + window_radius, dx + window_radius] += weight
                b = int(length / bin_step)
                if b < bins and 0 <= py < height and 0 <= px < width:
                    truth[block, b, py, px] += weight
