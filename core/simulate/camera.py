"""What the camera sees of a scattering event: next-event estimation through a flat surface.

Units: lengths in grid steps, coefficients per grid step; depth ``z`` grows downward from the
surface ``z = 0``; directions are ``(y, x, z)`` unit vectors. A scene direction
``[zenith, azimuth]`` in degrees is a direction of travel, zenith from straight down and azimuth
from +x toward +y: the projector's beam travels along it, the camera looks along it (so the
light it records travels the opposite way).

The quantity (docs/format/scene.md, "What a simulated frame holds") is the reflectance factor toward the
camera, ``pi L_o(p, w_o) A / P``: ``L_o`` the radiance leaving grid pixel ``p`` toward the camera
in air (direction ``w_o``, zenith ``th_o`` from the upward normal), averaged over the pixel of
area ``A = 1``, per unit beam power ``P``.

Derivation of the estimator. A photon of weight ``w`` (a fraction of the beam's power) scatters at
``x``, depth ``z``, arriving along ``u``. Inside, the light that leaves toward the camera travels
along ``w_i``, the camera direction refracted in: same azimuth, ``sin th_i = sin th_o / n``.
Scattered power goes into the solid angle ``dw_i`` around ``w_i`` with probability
``p_HG(u . w_i) dw_i`` (per steradian), and reaches the surface at the single point
``x + s w_i``, ``s = z / cos th_i``, with probability ``T(s) = exp(-tau(s))``, ``tau`` the optical
depth along that segment. Power crossing the surface element ``dA`` within ``dw_i`` is
``L_i cos th_i dA dw_i``, so this event adds to the pixel that point falls in

    integral over the pixel of L_i dA = w p_HG(u . w_i) T(s) / cos th_i.

Crossing the surface keeps ``L / n^2`` up to Fresnel transmission ``T_F(th_i)`` (etendue:
``n^2 cos th_i dw_i = cos th_o dw_o``), so ``L_o = T_F L_i / n^2`` and the event's contribution
to the reflectance factor is

    pi w p_HG(u . w_i) exp(-tau(s)) T_F(th_i) / (n^2 cos th_i).

Checks. (1) Integrated over camera directions, ``(value / pi) cos th_o dw_o`` becomes
``w p_HG T(s) T_F dw_i`` by the etendue relation: the probability that the scattered photon
leaves through the surface in ``dw_i`` on its next flight, so summed over the upper hemisphere
and over all scattering events, it is the exitance (every photon leaves, if at all, on the flight
after its last scattering, since the surface only sends it back down). (2) A surface that sends
out ``L_o`` equal in every direction, as a Lambertian one, has exitance ``pi L_o``: the
reflectance factor and the exitance agree, and a white one reads 1 at the lit pixel.

The optical depth is exact: a voxel traversal (Amanatides and Woo) sums ``mu_t`` times the length
of each voxel the segment crosses; a homogeneous volume skips it, and so does a camera straight
down, with a table of each voxel's optical depth to the surface. Estimates from deep in the
medium are tiny but as costly as the others, so past an optical depth of
:data:`ROULETTE_DEPTH` (the estimate is then below 0.25 % of its unattenuated value) the
traversal stops and plays Russian roulette: it goes on to the surface with probability
:data:`ROULETTE_SURVIVAL`, its value divided by that (unbiased). Beyond
:data:`OPTICAL_DEPTH_CUTOFF` the contribution (below 1e-17 of ``w``) is dropped. The roulette
draws from its own random stream, so the walk is the same whatever the measure.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .steps import CPU, Steps
from .tables import ANISOTROPY, MU_T

OPTICAL_DEPTH_CUTOFF = 40.0
ROULETTE_DEPTH = 6.0
ROULETTE_SURVIVAL = 0.1
MAX_COLUMN_VOXELS = 8 * 2**20

# Layout of the ``optics`` array the photon kernels take (see :func:`optics`).
INDEX, DEPTH, BEAM_Y, BEAM_X, BEAM_Z, ENTRY_WEIGHT, VIEW_Y, VIEW_X, VIEW_Z, VIEW_FACTOR, UNIFORM_MU_T = range(11)
OPTICS_SIZE = 11


exit_fresnel = CPU.exit_fresnel
"""Unpolarised Fresnel reflectance ``exit_fresnel(n, cos_inside)`` (:func:`.steps.exit_fresnel`, compiled for the CPU)."""


def specular_reflectance(n: float, zenith_deg: float = 0.0) -> float:
    """Fresnel reflectance of the surface for a beam from air at ``zenith_deg``;
    ((n - 1) / (n + 1))^2 at normal incidence."""
    return float(exit_fresnel(n, refracted_cosine(n, zenith_deg)))


def refracted_cosine(n: float, zenith_deg: float) -> float:
    """cos of the angle inside (Snell, sin th_i = sin th_o / n) for ``zenith_deg`` outside."""
    sin_inside = math.sin(math.radians(zenith_deg)) / n
    return math.sqrt(1.0 - sin_inside * sin_inside)


def _inside_direction(n: float, zenith_deg: float, azimuth_deg: float) -> np.ndarray:
    """(3,) ``(y, x, z)``: the direction ``[zenith, azimuth]`` of travel from air, refracted in."""
    sin_inside = math.sin(math.radians(zenith_deg)) / n
    azimuth = math.radians(azimuth_deg)
    return np.array([sin_inside * math.sin(azimuth), sin_inside * math.cos(azimuth),
                     math.sqrt(1.0 - sin_inside * sin_inside)])


def optics(n: float, depth: float, projector=(0.0, 0.0), camera=(0.0, 0.0),
           uniform_mu_t: float = -1.0) -> np.ndarray:
    """The (OPTICS_SIZE,) float64 array of a scene's geometry that the photon kernels take.

    Parameters
    ----------
    n
        Refractive index of the medium (air outside).
    depth
        Grid steps below the surface where light is lost.
    projector, camera
        ``[zenith, azimuth]`` in degrees, zenith in [0, 90).
    uniform_mu_t
        Non-negative when each channel's ``mu_t`` is the same in every voxel (the estimate then
        takes the scattering voxel's and skips the traversal), else negative.
    """
    values = np.zeros(OPTICS_SIZE)
    values[INDEX], values[DEPTH], values[UNIFORM_MU_T] = n, depth, uniform_mu_t
    beam = _inside_direction(n, *projector)
    values[BEAM_Y:BEAM_Z + 1] = beam
    values[ENTRY_WEIGHT] = 1.0 - exit_fresnel(n, beam[2])
    # The light toward the camera travels against the camera's viewing direction.
    view = -_inside_direction(n, *camera)
    values[VIEW_Y:VIEW_Z + 1] = view
    cos_inside = -view[2]
    values[VIEW_FACTOR] = math.pi * (1.0 - exit_fresnel(n, cos_inside)) / (n * n * cos_inside)
    return values


henyey_greenstein = CPU.henyey_greenstein
"""Henyey-Greenstein phase function per steradian ``henyey_greenstein(cos_angle, g)`` (:func:`.steps.henyey_greenstein`, compiled for the CPU)."""


def column_optical_depths(volume: np.ndarray, mu_t: np.ndarray, camera=(0.0, 0.0)) -> np.ndarray:
    """(C, D, H, W) float64 optical depth per channel (``mu_t`` (C, materials), or (materials,)
    for one) from the top of voxel ``[z, y, x]`` straight up to the surface, for a camera
    straight down in a heterogeneous volume of at most :data:`MAX_COLUMN_VOXELS` voxels per
    channel (the estimate then needs no traversal); else an empty (0, 0, 0, 0) array."""
    if camera[0] != 0.0 or volume.size > MAX_COLUMN_VOXELS:
        return np.zeros((0, 0, 0, 0))
    per_voxel = np.atleast_2d(mu_t)[:, volume]
    above = np.cumsum(per_voxel, axis=1)
    # C order whatever the channel count: the fancy index leaves channels innermost (numba's 'A'
    # layout, or 'F' for a one-pixel-wide volume), and every layout is one more compiled version of
    # the walk and of each kernel that calls it.
    return np.ascontiguousarray(np.concatenate([np.zeros((per_voxel.shape[0], 1) + volume.shape[1:]),
                                                above[:, :-1]], axis=1))


def column_depths(volume, tables, columns, material, z, y, x, out, channels):
    """Optical depth per channel straight up from ``(z, y, x)`` (in ``material``) into
    ``out[:channels]``: the voxels above (``columns``, :func:`column_optical_depths`), then this
    one's part."""
    layers, height, width = volume.shape
    iz = min(int(z), layers - 1)
    iy = min(max(int(math.floor(y + 0.5)), 0), height - 1)
    ix = min(max(int(math.floor(x + 0.5)), 0), width - 1)
    for c in range(channels):
        out[c] = columns[c, iz, iy, ix] + tables[MU_T + c, material] * (z - iz)


def traverse_to_surface(volume, mu_t, z, y, x, vy, vx, vz, limit, out):
    """Optical depth per channel (``mu_t`` (C, materials)) from ``(z, y, x)`` along
    ``(vy, vx, vz)`` (``vz < 0``) up to ``z = 0``, into ``out[:C]``, exact for the voxel volume
    (which repeats its edge voxels sideways); stops early, with every channel above ``limit``,
    once they all are past it."""
    length = z / -vz
    layers, height, width = volume.shape
    iz = min(int(z), layers - 1)
    iy = int(math.floor(y + 0.5))
    ix = int(math.floor(x + 0.5))
    # Distances along the ray to the next voxel face on each axis, and between faces.
    next_z = (z - iz) / -vz
    step_z = 1.0 / -vz
    if vy > 0.0:
        next_y, step_y, move_y = (iy + 0.5 - y) / vy, 1.0 / vy, 1
    elif vy < 0.0:
        next_y, step_y, move_y = (y - iy + 0.5) / -vy, -1.0 / vy, -1
    else:
        next_y, step_y, move_y = math.inf, math.inf, 0
    if vx > 0.0:
        next_x, step_x, move_x = (ix + 0.5 - x) / vx, 1.0 / vx, 1
    elif vx < 0.0:
        next_x, step_x, move_x = (x - ix + 0.5) / -vx, -1.0 / vx, -1
    else:
        next_x, step_x, move_x = math.inf, math.inf, 0
    travelled = 0.0
    channels = mu_t.shape[0]
    for c in range(channels):
        out[c] = 0.0
    while True:
        face = min(next_z, next_y, next_x, length)
        material = volume[iz, min(max(iy, 0), height - 1), min(max(ix, 0), width - 1)]
        least = math.inf
        for c in range(channels):
            out[c] += mu_t[c, material] * (face - travelled)
            least = min(least, out[c])
        if face >= length or least > limit:
            return
        travelled = face
        if face == next_z:
            iz -= 1
            next_z += step_z
            if iz < 0:  # rounding: the surface is reached
                return
        elif face == next_y:
            iy += move_y
            next_y += step_y
        else:
            ix += move_x
            next_x += step_x


def least_of(values, channels):
    """The least of ``values[:channels]``."""
    least = values[0]
    for c in range(1, channels):
        least = min(least, values[c])
    return least


def compile_estimate(jit, inline, steps: Steps):
    """``(optical_depth_to_surface, camera_estimate)`` compiled with ``jit`` (``inline`` for the
    small helpers) from the device's ``steps`` (:func:`ringlight.core.simulate.steps.compile_steps`):
    the one statement of the estimate that the CPU and the CUDA kernels compile.

    ``camera_estimate(state, volume, tables, columns, view, weights, material, z, y, x, uy, ux, uz,
    values)`` is the next-event estimate toward the camera from a scattering at ``(z, y, x)``, in
    ``material``, of a photon of ``weights`` (C,) (after the collision's factor) arriving along
    ``(uy, ux, uz)``; ``tables`` is :func:`ringlight.core.simulate.tables.walk_tables`, ``view``
    the optics' ``(VIEW_Y, VIEW_X, VIEW_Z, VIEW_FACTOR, UNIFORM_MU_T)`` as a tuple, ``columns``
    :func:`column_optical_depths` (or an empty array), ``state`` the estimator's own random stream
    (for the roulette, played on the least attenuated channel). It writes into ``values`` (C,) the
    contribution to the reflectance factor of the pixel around the point where the path to the
    camera leaves the surface, and returns
    ``(exit_y, exit_x, distance, scored)``: that point, the path's length inside,
    ``z / cos th_i``, and whether anything was scored.
    """
    uniform, henyey_greenstein = steps.uniform, steps.henyey_greenstein
    columns_up = inline(column_depths)
    traverse = jit(traverse_to_surface)
    least = inline(least_of)

    def camera_estimate(state, volume, tables, columns, view, weights, material, z, y, x, uy, ux, uz, values):
        vy, vx, vz, factor, uniform_mu_t = view
        distance = z / -vz
        scale = 1.0
        channels = (tables.shape[0] - MU_T) // 2
        mu_t = tables[MU_T:MU_T + channels]
        # A homogeneous volume needs no traversal (nor the call, whose array arguments cost about
        # as much as the rest of the estimate).
        if uniform_mu_t >= 0.0:
            for c in range(channels):
                values[c] = mu_t[c, material] * distance
        elif columns.shape[0] > 0:
            columns_up(volume, tables, columns, material, z, y, x, values, channels)
        else:
            traverse(volume, mu_t, z, y, x, vy, vx, vz, ROULETTE_DEPTH, values)
        if least(values, channels) > ROULETTE_DEPTH:
            if uniform(state) >= ROULETTE_SURVIVAL:
                return y, x, distance, False
            scale = 1.0 / ROULETTE_SURVIVAL
            if uniform_mu_t < 0.0 and columns.shape[0] == 0:
                traverse(volume, mu_t, z, y, x, vy, vx, vz, OPTICAL_DEPTH_CUTOFF, values)
            if least(values, channels) > OPTICAL_DEPTH_CUTOFF:
                return y, x, distance, False
        common = scale * factor * henyey_greenstein(uy * vy + ux * vx + uz * vz, tables[ANISOTROPY, material])
        for c in range(channels):
            # values holds each channel's optical depth; past the cutoff a channel adds nothing.
            values[c] = common * weights[c] * math.exp(-values[c]) if values[c] <= OPTICAL_DEPTH_CUTOFF else 0.0
        return y + distance * vy, x + distance * vx, distance, True

    return traverse, jit(camera_estimate)


optical_depth_to_surface, camera_estimate = compile_estimate(numba.njit(cache=True),
                                                             numba.njit(cache=True, inline="always"), CPU)
"""The estimate compiled for the CPU (:func:`compile_estimate`)."""
