"""The simulator's photon kernels on an NVIDIA GPU: :func:`.photon.simulate_points` and
:func:`.photon.simulate_differences` with the same walk (:func:`.walk.compile_walk` and
:func:`.camera.compile_estimate`, compiled as CUDA device functions from the same statement of
the steps, :mod:`ringlight.core.simulate.steps`), one thread per lit point, the windows and the
path-length images summed with atomic adds.

Thread ``i`` walks lit point ``i``'s photons on its walk stream ``(seed, streams[i])`` and its
estimator stream, exactly as the CPU's kernels walk them: the sums differ only in the order of
their additions. The path-length images come back in block 0 of ``truth`` (the CPU's blocks exist
to make its parallel sums deterministic; the device's atomic sums are not, to the last bit).
This module imports numba's CUDA target: import it only for a CUDA run.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import cuda, float64, uint64

from .camera import compile_estimate
from .walk import RECORD_FIELDS, WEIGHTS, compile_walk, fill_walker
from .steps import cuda_steps
from .streams import thread_streams, walk_and_estimator_states
from .tables import MU_T

THREADS_PER_BLOCK = 64
MOST_CHANNELS = 3
"""Channels a walk carries at most (its scratch lives in each thread's local memory)."""
WALKER_SIZE = WEIGHTS + MOST_CHANNELS
BUFFERS_SHAPE = (3, MOST_CHANNELS)
"""Local arrays take shapes known when the kernel compiles: a walker's, and
:func:`.photon.walk_buffers`' rows."""


def atomic_add(array, index, value):
    """The device's tally: ``array[index] += value``, atomically (threads share the images)."""
    cuda.atomic.add(array, index, value)


def no_record(records, count, photon, entry_y, entry_x, surface_y, surface_x, length, values, sign, channels):
    """The device keeps no event list (the CPU's is for tests and inspection)."""


@functools.cache
def _kernels():
    """``(points_kernel, differences_kernel)``, compiled on first use."""
    device = cuda.jit(device=True)
    steps = cuda_steps()
    _, camera_estimate = compile_estimate(device, device, steps)
    walk = compile_walk(device, device, steps, camera_estimate, device(atomic_add), device(no_record))
    uniform, fresh_state, enter, streams_of = steps.uniform, steps.fresh_state, device(fill_walker), \
        device(thread_streams)

    @device
    def enter_point(walker, state, ly, lx, optics, channels):
        """A photon entering uniformly over pixel ``(ly, lx)`` (two uniforms of ``state``, as the
        CPU draws them), into ``walker``; returns where it entered."""
        entry_y = ly + uniform(state) - 0.5
        entry_x = lx + uniform(state) - 0.5
        enter(walker, entry_y, entry_x, optics, channels)
        return entry_y, entry_x

    @cuda.jit
    def points_kernel(volume, tables, majorant, optics, columns, camera, lit, photons, states, bin_step, windows,
                      truth, records, no_map):
        i = cuda.grid(1)
        count = lit.shape[0]
        if i >= count:
            return
        channels = (tables.shape[0] - MU_T) // 2
        state = cuda.local.array(2, uint64)
        estimator_state = cuda.local.array(2, uint64)
        streams_of(states, i, count, state, estimator_state)
        walker = cuda.local.array(WALKER_SIZE, float64)
        buffers = cuda.local.array(BUFFERS_SHAPE, float64)
        ly = lit[i, 0]
        lx = lit[i, 1]
        for _ in range(photons):
            entry_y, entry_x = enter_point(walker, state, ly, lx, optics, channels)
            walk(state, estimator_state, walker, False, volume, tables, majorant, optics, columns, camera, windows[i],
                 ly, lx, truth, bin_step, records, 0, 0, entry_y, entry_x, 1.0, no_map, walker, state,
                 estimator_state, buffers)

    @cuda.jit
    def differences_kernel(volume, reference, mixed, tables, majorant, optics, reference_optics, columns,
                           reference_columns, camera, lit, photons, direct, seeders, bin_step, windows, truth,
                           touches, records, no_map):
        i = cuda.grid(1)
        count = lit.shape[0]
        if i >= count:
            return
        channels = (tables.shape[0] - MU_T) // 2
        seeder = cuda.local.array(2, uint64)
        estimator_seeder = cuda.local.array(2, uint64)
        streams_of(seeders, i, count, seeder, estimator_seeder)
        state = cuda.local.array(2, uint64)
        estimator_state = cuda.local.array(2, uint64)
        saved_state = cuda.local.array(2, uint64)
        saved_estimator_state = cuda.local.array(2, uint64)
        walker = cuda.local.array(WALKER_SIZE, float64)
        saved = cuda.local.array(WALKER_SIZE, float64)
        buffers = cuda.local.array(BUFFERS_SHAPE, float64)
        ly = lit[i, 0]
        lx = lit[i, 1]
        share = 1.0 / photons[i]
        for _ in range(photons[i]):
            # As the CPU's kernel: each photon its own streams, so that the reference walk can take
            # them up where the scene's walk reached a marked voxel.
            fresh_state(seeder, state)
            fresh_state(estimator_seeder, estimator_state)
            entry_y, entry_x = enter_point(walker, state, ly, lx, optics, channels)
            _, reached = walk(state, estimator_state, walker, False, volume, tables, majorant, optics, columns, camera,
                              windows[i], ly, lx, truth, bin_step, records, 0, 0, entry_y, entry_x, share,
                              no_map if direct[i] else mixed, saved, saved_state, saved_estimator_state, buffers)
            if reached:
                touches[i] += 1
                walk(saved_state, saved_estimator_state, saved, True, reference, tables, majorant, reference_optics,
                     reference_columns, camera, windows[i], ly, lx, truth, bin_step, records, 0, 0, entry_y,
                     entry_x, -share, no_map, saved, saved_state, saved_estimator_state, buffers)

    return points_kernel, differences_kernel


def _on_device(array):
    """``array`` copied to the device (C-contiguous: a kernel's arrays are typed by their layout)."""
    return cuda.to_device(np.ascontiguousarray(array))


def _launch(kernel, count: int, *arguments) -> None:
    """Run ``kernel`` with one thread per lit point."""
    threads = max(1, min(THREADS_PER_BLOCK, count))
    kernel[-(-count // threads), threads](*arguments)


def _device_outputs(windows: np.ndarray, truth: np.ndarray, channels: int):
    """The device's windows (as given), path-length images (truth's without its blocks) and the
    empty record list and map."""
    if channels > MOST_CHANNELS:
        raise ValueError(f"a CUDA walk carries at most {MOST_CHANNELS} channels, not {channels}")
    return (_on_device(windows), _on_device(np.zeros(truth.shape[1:])),
            _on_device(np.zeros((0, RECORD_FIELDS + channels))), _on_device(np.zeros((0, 0, 0), np.bool_)))


def simulate_points_cuda(volume, tables, majorant, optics, columns, camera, lit, photons, seed, streams, bin_step,
                         windows, truth) -> None:
    """:func:`.photon.simulate_points` on the current CUDA device (the same arguments and outputs;
    the path-length images are added to ``truth``'s block 0)."""
    count = len(lit)
    if count == 0:
        return
    device_windows, device_truth, records, no_map = _device_outputs(windows, truth, (tables.shape[0] - MU_T) // 2)
    _launch(_kernels()[0], count, _on_device(volume), _on_device(tables), float(majorant),
            _on_device(optics), _on_device(columns), bool(camera), _on_device(lit),
            int(photons), _on_device(walk_and_estimator_states(seed, streams)), float(bin_step), device_windows, device_truth,
            records, no_map)
    windows[...] = device_windows.copy_to_host()
    truth[0] += device_truth.copy_to_host()


def simulate_differences_cuda(volume, reference, mixed, tables, majorant, optics, reference_optics, columns,
                              reference_columns, camera, lit, photons, direct, seed, streams, bin_step, windows, truth,
                              touches) -> None:
    """:func:`.photon.simulate_differences` on the current CUDA device (the same arguments and
    outputs; the path-length images are added to ``truth``'s block 0)."""
    count = len(lit)
    if count == 0:
        return
    device_windows, device_truth, records, no_map = _device_outputs(windows, truth, (tables.shape[0] - MU_T) // 2)
    device_touches = _on_device(touches)
    _launch(_kernels()[1], count, _on_device(volume), _on_device(reference), _on_device(mixed),
            _on_device(tables), float(majorant), _on_device(optics), _on_device(reference_optics),
            _on_device(columns), _on_device(reference_columns), bool(camera),
            _on_device(lit), _on_device(photons), _on_device(direct),
            _on_device(walk_and_estimator_states(seed, streams)), float(bin_step), device_windows, device_truth,
            device_touches, records, no_map)
    windows[...] = device_windows.copy_to_host()
    truth[0] += device_truth.copy_to_host()
    touches[...] = device_touches.copy_to_host()
