"""The photon walk in a voxel volume below a flat surface, written once for the CPU and CUDA.

:func:`compile_walk` is the one statement of the walk and its scoring; :mod:`.photon` compiles it
with numba for the CPU (and runs its kernels there), :mod:`.photon_cuda` as CUDA device functions.

Units: lengths in grid steps, coefficients per grid step. Depth ``z`` grows downward from the
surface ``z = 0``; lateral position ``(y, x)`` in grid coordinates (pixel centres on integers).
One photon enters at a given point carrying one weight per colour channel of its walk (channels
that scatter alike share walks: :mod:`ringlight.core.simulate.tables`, whose ``tables`` array
every kernel takes); the scene's geometry comes in an ``optics`` array
(:func:`ringlight.core.simulate.camera.optics`):

- Entry: the beam refracts in along the projector's direction; the photon starts with the
  Fresnel transmission at that angle as its weight (the specular part is not simulated).
- Free paths by delta (Woodcock) tracking against a majorant, so heterogeneous voxels need no
  ray marching; a tentative collision is real with probability ``mu_w / majorant``, and each
  channel's weight takes the factors of :mod:`.tables` (with one channel: implicit capture,
  the weight times the albedo at a real collision).
- At a real collision the photon scatters by Henyey-Greenstein; once every channel's weight is
  below 1e-4, Russian roulette keeps 1 in 10.
- At the surface, unpolarised Fresnel reflection with total internal reflection, sampled
  (reflect with probability R, else exit with the full weight); through ``z = depth`` it is lost.

What is scored (each score is a value per channel at a surface position with a path length):

- ``camera`` measure: at every real scattering, after its weight factor, the next-event
  estimate of the light leaving toward the camera
  (:func:`ringlight.core.simulate.camera.camera_estimate`), at the pixel where the path to the
  camera meets the surface, with path length the length so far plus that path's. The walk
  itself goes on unchanged, so its analogue exits are not scored.
- ``exitance`` measure: the weights of each photon that leaves, where it leaves, with its length.

Either way the walk and its random numbers are the same, so further estimators attach at the
scattering vertex without touching the walk.
"""

from __future__ import annotations

import math

from .camera import (
    BEAM_X,
    BEAM_Y,
    BEAM_Z,
    DEPTH,
    ENTRY_WEIGHT,
    INDEX,
    UNIFORM_MU_T,
    VIEW_FACTOR,
    VIEW_X,
    VIEW_Y,
    VIEW_Z,
)
from .steps import Steps
from .tables import ANISOTROPY, MU_T, SCATTER, WALK_MU

ROULETTE_WEIGHT = 1e-4
ROULETTE_SURVIVAL = 0.1
RECORD_FIELDS = 6
"""Leading columns of an event record: photon, entry y, entry x, surface y, surface x, path
length; then one value per channel."""
WEIGHTS = 7
"""A walker's state: y, x, z, uy, ux, uz, path length, then one weight per channel from here."""
TOTALS = 0
"""Row of :func:`walk_buffers` that receives the sum of the values a walk scores."""


def keep_record(records, count, photon, entry_y, entry_x, surface_y, surface_x, length, values, sign, channels):
    """Row ``count`` of ``records`` (the CPU's event list for tests and inspection), when there is
    room: ``[photon, entry_y, entry_x, surface_y, surface_x, length, sign * value per channel]``."""
    if count < records.shape[0]:
        records[count, 0] = photon
        records[count, 1] = entry_y
        records[count, 2] = entry_x
        records[count, 3] = surface_y
        records[count, 4] = surface_x
        records[count, 5] = length
        for c in range(channels):
            records[count, RECORD_FIELDS + c] = sign * values[c]


def add_in_place(array, index, value):
    """``array[index] += value``: the CPU's tally (a CUDA kernel adds atomically instead)."""
    array[index] += value


def fill_walker(walker, entry_y, entry_x, optics, channels):
    """Fill ``walker`` (at least WEIGHTS + channels) with a photon that has just refracted in at
    ``(entry_y, entry_x)``."""
    walker[0] = entry_y
    walker[1] = entry_x
    walker[2] = 0.0
    walker[3] = optics[BEAM_Y]
    walker[4] = optics[BEAM_X]
    walker[5] = optics[BEAM_Z]
    walker[6] = 0.0
    for c in range(channels):
        walker[WEIGHTS + c] = optics[ENTRY_WEIGHT]


def compile_walk(jit, inline, steps: Steps, camera_estimate, add, record):
    """The walk (:func:`.photon.walk` on the CPU) compiled with ``jit`` (``inline`` for the small
    helpers) from the device's ``steps`` (:func:`ringlight.core.simulate.steps.compile_steps`), its
    compiled ``camera_estimate`` (:func:`ringlight.core.simulate.camera.compile_estimate`), its
    tally ``add(array, index, value)`` (:func:`add_in_place`, or an atomic add) and its ``record``
    (as :func:`keep_record`, or nothing): the one statement of the walk and its scoring that the
    CPU and the CUDA kernels compile."""
    uniform, exit_fresnel, flight_to_surface = steps.uniform, steps.exit_fresnel, steps.flight_to_surface
    scatter_direction = steps.scatter

    def score(window, centre_y, centre_x, truth, bin_step, records, count, photon, entry_y, entry_x,
              surface_y, surface_x, length, values, sign, channels):
        """Add ``sign * values`` (C,) to the lit point's window (offsets from ``(centre_y,
        centre_x)``), to the path-length image of its bin, and to the records; returns the number
        of events so far (it may exceed the records' rows: the caller sees the overflow)."""
        py = int(math.floor(surface_y + 0.5))
        px = int(math.floor(surface_x + 0.5))
        radius = window.shape[0] // 2
        dy = py - centre_y
        dx = px - centre_x
        if abs(dy) <= radius and abs(dx) <= radius:
            for c in range(channels):
                add(window, (dy + radius, dx + radius, c), sign * values[c])
        b = int(length / bin_step)
        if b < truth.shape[0] and 0 <= py < truth.shape[1] and 0 <= px < truth.shape[2]:
            for c in range(channels):
                add(truth, (b, py, px, c), sign * values[c])
        record(records, count, photon, entry_y, entry_x, surface_y, surface_x, length, values, sign, channels)
        return count + 1

    tally = inline(score)

    def walk(state, estimator_state, walker, pending, volume, tables, majorant, optics, columns, camera, window,
             centre_y, centre_x, truth, bin_step, records, count, photon, entry_y, entry_x, sign, mixed,
             saved_walker, saved_state, saved_estimator_state, buffers):
        layers, height, width = volume.shape
        channels = (tables.shape[0] - MU_T) // 2
        n = optics[INDEX]
        depth = optics[DEPTH]
        y, x, z, uy, ux, uz, length = walker[0], walker[1], walker[2], walker[3], walker[4], walker[5], walker[6]
        totals = buffers[TOTALS]
        weights = buffers[TOTALS + 1]
        for c in range(channels):
            weights[c] = walker[WEIGHTS + c]
        values = buffers[TOTALS + 2]
        view = (optics[VIEW_Y], optics[VIEW_X], optics[VIEW_Z], optics[VIEW_FACTOR], optics[UNIFORM_MU_T])
        touched = mixed.shape[0] == 0
        reached = False
        while True:
            if pending:
                pending = False
            else:
                step = -math.log(1.0 - uniform(state)) / majorant
                travel = flight_to_surface(z, uz, step)
                if travel >= 0.0:
                    y += travel * uy
                    x += travel * ux
                    length += travel
                    z = 0.0
                    if uniform(state) < exit_fresnel(n, -uz):
                        uz = -uz
                        continue
                    if not camera and touched:
                        count = tally(window, centre_y, centre_x, truth, bin_step, records, count, photon,
                                      entry_y, entry_x, y, x, length, weights, sign, channels)
                        for c in range(channels):
                            totals[c] += weights[c]
                    return count, reached
                if uz > 0.0 and z + step * uz >= depth:
                    return count, reached
                y += step * uy
                x += step * ux
                z += step * uz
                length += step
                if not touched and mixed[min(int(z), layers - 1), min(max(int(math.floor(y + 0.5)), 0), height - 1),
                                         min(max(int(math.floor(x + 0.5)), 0), width - 1)]:
                    touched = True
                    reached = True
                    saved_walker[0] = y
                    saved_walker[1] = x
                    saved_walker[2] = z
                    saved_walker[3] = uy
                    saved_walker[4] = ux
                    saved_walker[5] = uz
                    saved_walker[6] = length
                    for c in range(channels):
                        saved_walker[WEIGHTS + c] = weights[c]
                    for i in range(2):
                        saved_state[i] = state[i]
                        saved_estimator_state[i] = estimator_state[i]
            iz = min(int(z), layers - 1)
            iy = min(max(int(math.floor(y + 0.5)), 0), height - 1)
            ix = min(max(int(math.floor(x + 0.5)), 0), width - 1)
            material = volume[iz, iy, ix]
            if uniform(state) * majorant >= tables[WALK_MU, material]:
                # A null collision: the majorant's fictitious particles (each channel's own share).
                for c in range(channels):
                    weights[c] *= tables[MU_T + channels + c, material]
                continue
            factor = tables[SCATTER, material]
            heaviest = 0.0
            for c in range(channels):
                weights[c] *= factor
                heaviest = max(heaviest, weights[c])
            anisotropy = tables[ANISOTROPY, material]
            if camera:
                surface_y, surface_x, distance, scored = camera_estimate(
                    estimator_state, volume, tables, columns, view, weights, material, z, y, x, uy, ux, uz, values)
                if scored and touched:
                    count = tally(window, centre_y, centre_x, truth, bin_step, records, count, photon,
                                  entry_y, entry_x, surface_y, surface_x, length + distance, values, sign, channels)
                    for c in range(channels):
                        totals[c] += values[c]
            uy, ux, uz = scatter_direction(state, uy, ux, uz, anisotropy)
            if heaviest < ROULETTE_WEIGHT:
                if uniform(state) < ROULETTE_SURVIVAL:
                    for c in range(channels):
                        weights[c] /= ROULETTE_SURVIVAL
                else:
                    return count, reached

    return jit(walk)
