"""The simulator's photon kernels on the CPU (numba): the walk of :mod:`.walk` compiled for the CPU,
and the runs that trace photons with it.

Units: lengths in grid steps, coefficients per grid step; what a walk does and scores is said in
:mod:`.walk`. Random numbers (:mod:`ringlight.core.simulate.streams`): one stream per lit point and
channel group for the walk and another for the estimator, so results do not depend on the number
of threads and the walk does not depend on the measure.
"""

from __future__ import annotations

import numba
import numpy as np

from ..device import Device
from .camera import BEAM_Z, DEPTH, ENTRY_WEIGHT, INDEX, OPTICS_SIZE, camera_estimate
from .steps import CPU
from .streams import ESTIMATOR_STREAM, fresh_state, seed_state, uniform
from .tables import channel_count
from .walk import RECORD_FIELDS, TOTALS, WEIGHTS, add_in_place, compile_walk, fill_walker, keep_record

NO_MAP = np.zeros((0, 0, 0), np.bool_)
"""An empty ``mixed`` map: no voxel is tracked."""


@numba.njit(cache=True, inline="always")
def walk_buffers(channels):
    """(3, channels) float64 zeros: row :data:`.walk.TOTALS`, then the walk's own scratch rows (its
    weights and one estimate per channel), allocated once per caller instead of once per walk."""
    return np.zeros((3, channels))


_CPU_INLINE = numba.njit(cache=True, inline="always")
walk = compile_walk(numba.njit(cache=True), _CPU_INLINE, CPU, camera_estimate, _CPU_INLINE(add_in_place),
                    _CPU_INLINE(keep_record))
walk.__doc__ = """``walk(state, estimator_state, walker, pending, volume, tables, majorant, optics, columns,
camera, window, centre_y, centre_x, truth, bin_step, records, count, photon, entry_y, entry_x, sign,
mixed, saved_walker, saved_state, saved_estimator_state, buffers)``, compiled for the CPU
(:func:`.walk.compile_walk`).

Walk from ``walker`` (``WEIGHTS + C``) until the light leaves, is lost or absorbed,
scoring as :func:`trace_photon` does, times ``sign``, and adding the values scored to row
:data:`.walk.TOTALS` of ``buffers`` (:func:`walk_buffers`); ``pending``: the walker stands at a
tentative collision not yet decided (else it is about to fly). ``walker`` itself is not changed.

``mixed`` ((D, H, W) bool, or the empty :data:`NO_MAP`) marks the voxels where the walk or
its scores can differ from those in a reference volume
(:func:`ringlight.core.simulate.reference.mixed_voxels`). Given one, nothing is scored before
the walk's first tentative collision in a marked voxel; there the walker
and both random states are saved (into ``saved_walker``, ``saved_state``,
``saved_estimator_state``) and scoring starts. Before that point the same random numbers
walk the same way, with the same scores, in the reference volume.
Returns ``(count, touched)``: events scored, and whether the walk reached a marked voxel.
"""
_fill_walker = _CPU_INLINE(fill_walker)


@numba.njit(cache=True)
def trace_photon(state, estimator_state, entry_y, entry_x, volume, tables, majorant, optics, columns, camera,
                 window, centre_y, centre_x, truth, bin_step, records, count, photon, buffers):
    """Trace one photon entering at ``(entry_y, entry_x)`` and score it (see :mod:`.walk`);
    ``state`` drives the walk, ``estimator_state`` the estimator.

    ``tables`` and ``majorant`` are :func:`ringlight.core.simulate.tables.walk_tables` (C
    channels); ``columns`` is :func:`ringlight.core.simulate.camera.column_optical_depths` (or
    empty). ``window`` ((2R+1, 2R+1, C), offsets from the lit point ``(centre_y, centre_x)``),
    ``truth`` ((bins, H, W, C), bins of ``bin_step``) and ``records`` ((k, RECORD_FIELDS + C),
    from row ``count``; zero rows to record nothing) receive the scores; ``camera`` picks the
    measure. ``buffers`` is :func:`walk_buffers`; its row :data:`TOTALS` receives the sum of this
    photon's values. Returns the number of events scored so far.
    """
    walker = entering_walker(entry_y, entry_x, optics, channel_count(tables))
    count, _ = walk(state, estimator_state, walker, False, volume, tables, majorant, optics, columns, camera, window,
                    centre_y, centre_x, truth, bin_step, records, count, photon, entry_y, entry_x, 1.0, NO_MAP,
                    walker, state, estimator_state, buffers)
    return count


@numba.njit(cache=True, inline="always")
def entering_walker(entry_y, entry_x, optics, channels):
    """(WEIGHTS + channels,) the walker of a photon that has just refracted in at
    ``(entry_y, entry_x)``."""
    walker = np.empty(WEIGHTS + channels)
    _fill_walker(walker, entry_y, entry_x, optics, channels)
    return walker


@numba.njit(cache=True, nogil=True)
def total_run(volume, tables, majorant, optics, camera, photons, seed, stream):
    """Trace ``photons`` entering uniformly over the pixel at the origin; returns ``(sums,
    sums of squares)`` (C,) over photons of each photon's total score (everything it scores,
    wherever; 0 for a photon that scores nothing), for the mean and its standard error: the
    exitance, or the reflectance factor toward the camera summed over the surface."""
    channels = channel_count(tables)
    window = np.zeros((1, 1, channels))
    truth = np.zeros((0, 1, 1, channels))
    records = np.zeros((0, RECORD_FIELDS + channels))
    columns = np.zeros((0, 0, 0, 0))
    state = seed_state(seed, stream)
    estimator_state = seed_state(seed, stream + ESTIMATOR_STREAM)
    sums = np.zeros(channels)
    squares = np.zeros(channels)
    buffers = walk_buffers(channels)
    totals = buffers[TOTALS]
    # The centre and the record counters as int64, not literal 0s: numba compiles a callee once
    # per literal argument, and the walk is the costliest compile of the simulator; every caller
    # passes these as plain int64.
    zero = np.int64(0)
    for _ in range(photons):
        totals[:] = 0.0
        trace_photon(state, estimator_state, uniform(state) - 0.5, uniform(state) - 0.5, volume, tables, majorant,
                     optics, columns, camera, window, zero, zero, truth, 1.0, records, zero, zero, buffers)
        sums += totals
        squares += totals * totals
    return sums, squares


@numba.njit(cache=True, nogil=True)
def reflectance_run(volume, tables, majorant, n, depth, photons, seed, stream):
    """:func:`total_run` of the exitance for a beam straight down, with weights relative to the
    light that got in (the entry's Fresnel loss is the caller's)."""
    # A plain bool, not a literal False, for the reason total_run passes int64 zeros.
    return total_run(volume, tables, majorant, _normal_incidence(n, depth), np.bool_(False), photons, seed, stream)


@numba.njit(cache=True)
def _normal_incidence(n, depth):
    """The optics of a beam straight down whose photons start with weight 1."""
    geometry = np.zeros(OPTICS_SIZE)
    geometry[INDEX] = n
    geometry[DEPTH] = depth
    geometry[BEAM_Z] = 1.0
    geometry[ENTRY_WEIGHT] = 1.0
    return geometry


@numba.njit(cache=True, nogil=True)
def trace_events(volume, tables, majorant, optics, camera, y, x, photons, seed, stream, capacity):
    """Every score of ``photons`` entering pixel ``(y, x)`` (uniformly over it), as
    (events, RECORD_FIELDS + C) float64 rows ``[photon, entry_y, entry_x, surface_y,
    surface_x, length, value per channel]`` (for tests and inspection). Raises if more than
    ``capacity`` events."""
    channels = channel_count(tables)
    state = seed_state(seed, stream)
    estimator_state = seed_state(seed, stream + ESTIMATOR_STREAM)
    records = np.zeros((capacity, RECORD_FIELDS + channels))
    window = np.zeros((1, 1, channels))
    truth = np.zeros((0, 1, 1, channels))
    columns = np.zeros((0, 0, 0, 0))
    buffers = walk_buffers(channels)
    count = np.int64(0)  # not a literal 0 either: trace_photon compiled once more for it
    origin = np.int64(0)  # not a literal 0: see total_run's zero
    for i in range(photons):
        entry_y = y + uniform(state) - 0.5
        entry_x = x + uniform(state) - 0.5
        count = trace_photon(state, estimator_state, entry_y, entry_x, volume, tables, majorant, optics, columns,
                             camera, window, origin, origin, truth, 1.0, records, count, i, buffers)
    if count > capacity:
        raise ValueError("trace_events: more events than capacity")
    return records[:count]


@numba.njit(parallel=True, cache=True, nogil=True)
def simulate_points(volume, tables, majorant, optics, columns, camera, lit, photons, seed, streams, bin_step,
                    windows, truth):
    """Trace ``photons`` from each lit point ``lit[i] = [y, x]`` with random stream ``streams[i]``
    (``tables``, ``majorant``, ``optics``, ``columns``, ``camera`` as in :func:`trace_photon`).

    ``windows`` (len(lit), 2R+1, 2R+1, C) float64 receives the scores around each lit point
    (offset ``[dy + R, dx + R]``); ``truth`` (blocks, bins, H, W, C) float64 receives every
    score inside the grid by path-length bin ``floor(length / bin_step)``, lit point ``i`` into
    block ``i * blocks // len(lit)``, so that summing blocks in order gives the same result
    whatever the number of threads. Values are raw (not divided by photons).
    """
    count = lit.shape[0]
    blocks = truth.shape[0]
    channels = channel_count(tables)
    for block in numba.prange(blocks):
        records = np.zeros((0, RECORD_FIELDS + channels))
        buffers = walk_buffers(channels)
        nothing_recorded = np.int64(0)  # not a literal 0: see total_run
        for i in range(block * count // blocks, (block + 1) * count // blocks):
            state = seed_state(seed, streams[i])
            estimator_state = seed_state(seed, streams[i] + ESTIMATOR_STREAM)
            ly = lit[i, 0]
            lx = lit[i, 1]
            for _ in range(photons):
                trace_photon(state, estimator_state, ly + uniform(state) - 0.5, lx + uniform(state) - 0.5, volume,
                             tables, majorant, optics, columns, camera, windows[i], ly, lx, truth[block], bin_step,
                             records, nothing_recorded, nothing_recorded, buffers)


@numba.njit(parallel=True, cache=True, nogil=True)
def simulate_differences(volume, reference, mixed, tables, majorant, optics, reference_optics, columns,
                         reference_columns, camera, lit, photons, direct, seed, streams, bin_step, windows, truth,
                         touches):
    """The correlated differences of :mod:`ringlight.core.simulate.reference`: for each lit point
    ``i`` (but those marked ``direct``), ``photons[i]`` walks in ``volume`` scored with +1 / photons[i] from their first
    tentative collision in a ``mixed`` voxel on, each then walked on from that point with the
    same random numbers in ``reference`` (the reference volume, its own ``reference_optics`` and
    ``reference_columns``; the same material tables and majorant) and scored with
    -1 / photons[i]. Before that point, and for walks that never reach a marked voxel, both
    volumes give the same scores: their difference is zero. A ``direct`` point's ``photons[i]``
    walks are scored whole in ``volume`` instead (its mean response, not a difference; no walk
    of it counts as reaching). ``touches[i]`` (int64) receives how many of point ``i``'s walks
    reached a marked voxel. Other arguments and the outputs as in
    :func:`simulate_points`; values are mean differences per photon (per point, not raw sums)."""
    count = lit.shape[0]
    blocks = truth.shape[0]
    channels = channel_count(tables)
    for block in numba.prange(blocks):
        records = np.zeros((0, RECORD_FIELDS + channels))
        buffers = walk_buffers(channels)
        nothing_recorded = np.int64(0)  # not a literal 0: see total_run
        for i in range(block * count // blocks, (block + 1) * count // blocks):
            seeder = seed_state(seed, streams[i])
            estimator_seeder = seed_state(seed, streams[i] + ESTIMATOR_STREAM)
            state = np.empty(2, np.uint64)
            estimator_state = np.empty(2, np.uint64)
            ly = lit[i, 0]
            lx = lit[i, 1]
            share = 1.0 / photons[i]
            saved = np.empty(WEIGHTS + channels)
            saved_state = np.empty(2, np.uint64)
            saved_estimator_state = np.empty(2, np.uint64)
            for _ in range(photons[i]):
                # Each photon its own streams, so that the reference walk can take them up where
                # the scene's walk reached a marked voxel, and no other photon reuses them.
                fresh_state(seeder, state)
                fresh_state(estimator_seeder, estimator_state)
                entry_y = ly + uniform(state) - 0.5
                entry_x = lx + uniform(state) - 0.5
                _, reached = walk(state, estimator_state, entering_walker(entry_y, entry_x, optics, channels), False,
                                  volume, tables, majorant, optics, columns, camera, windows[i], ly, lx, truth[block],
                                  bin_step, records, nothing_recorded, nothing_recorded, entry_y, entry_x, share,
                                  NO_MAP if direct[i] else mixed, saved, saved_state, saved_estimator_state, buffers)
                if reached:
                    touches[i] += 1
                    walk(saved_state, saved_estimator_state, saved, True, reference, tables, majorant,
                         reference_optics, reference_columns, camera, windows[i], ly, lx, truth[block], bin_step,
                         records, nothing_recorded, nothing_recorded, entry_y, entry_x, -share, NO_MAP, saved,
                         saved_state, saved_estimator_state, buffers)


def point_kernels(device: Device | None = None):
    """``(simulate_points, simulate_differences)`` for ``device`` (the CPU's when None; on a CUDA
    device :mod:`.photon_cuda`'s, which take the same arguments)."""
    if device is not None and device.is_cuda:
        from .photon_cuda import simulate_differences_cuda, simulate_points_cuda

        return simulate_points_cuda, simulate_differences_cuda
    return simulate_points, simulate_differences
