"""The white run of a layered slab (:mod:`.white_mc`) on an NVIDIA GPU: the same photon walk
(:func:`.white_mc.compile_walk`, compiled as CUDA device functions from the same statement of the
steps, :mod:`ringlight.core.simulate.steps`), one random stream per thread, each record's row
taken from an atomic counter.

Thread ``t`` traces its share of the photons on walk stream ``(seed, t)`` and estimator stream
``(seed, t + ESTIMATOR_STREAM)``, numbered from the first photon of its share, so that it makes
exactly the records that the CPU's :func:`.white_mc._white_block` makes on that stream; the
records are put back in the CPU's order (by photon, each photon's in the order of its walk). The
CPU's run of the same photons uses :data:`.white_mc.BLOCKS` streams: a CUDA run is another sample
of it. This module imports numba's CUDA target: import it only for a CUDA run.
"""

from __future__ import annotations

import functools
import time

import numpy as np
from numba import cuda, float64, uint64

from ..simulate.steps import CPU, cuda_steps
from ..simulate.streams import thread_share, thread_streams, walk_and_estimator_states
from .white_mc import (BLOCKS, DatabaseError, SlabOptics, WhiteDatabase, _white_block, compile_walk,
                       write_record)

STREAMS = 1 << 15
"""Threads (one random stream each) of a CUDA run, fewer when there are fewer photons."""
THREADS_PER_BLOCK = 128
MOST_BINS = 64
"""Depth bins a CUDA run takes (its scratch lives in each thread's local memory)."""
PILOT_PHOTONS = 64


@functools.cache
def _kernel():
    """The CUDA kernel, compiled on first use."""

    write = cuda.jit(device=True)(write_record)

    def record(count, counter, pixel, value, lengths_out, photon_out, cell, estimate, lengths, up, photon):
        write(cuda.atomic.add(counter, 0, 1), pixel, value, lengths_out, photon_out, cell, estimate, lengths, up,
              photon)
        return count + 1

    trace_photon = compile_walk(cuda.jit(device=True), cuda_steps(), cuda.jit(device=True)(record))
    streams_of, share_of = cuda.jit(device=True)(thread_streams), cuda.jit(device=True)(thread_share)

    @cuda.jit
    def white_kernel(mus, majorant, g, n, depth, reach, constant, photons, states, counter, pixel, value,
                     lengths_out, photon_out):
        stream = cuda.grid(1)
        streams = states.shape[0] // 2
        if stream >= streams:
            return
        state = cuda.local.array(2, uint64)
        estimator_state = cuda.local.array(2, uint64)
        streams_of(states, stream, streams, state, estimator_state)
        lengths = cuda.local.array(MOST_BINS, float64)
        up = cuda.local.array(MOST_BINS, float64)
        first, count = share_of(photons, streams, stream)
        for p in range(count):
            trace_photon(state, estimator_state, mus, majorant, g, n, depth, reach, constant, lengths, up, first + p,
                         0, counter, pixel, value, lengths_out, photon_out)

    return white_kernel


def run_white_cuda(optics: SlabOptics, photons: int, seed: int = 0, streams: int = STREAMS) -> WhiteDatabase:
    """:func:`.white_mc.run_white` on the current CUDA device: its photons (rounded up to whole
    :data:`.white_mc.BLOCKS`) shared among ``streams`` threads, the first ones one more each.
    DatabaseError for more than :data:`MOST_BINS` depth bins."""
    if optics.bins > MOST_BINS:
        raise DatabaseError(f"a CUDA white run takes at most {MOST_BINS} depth bins, not {optics.bins}; "
                            "use --device cpu")
    start = time.perf_counter()
    mus = np.asarray(optics.mus, np.float64)
    traced = -(-photons // BLOCKS) * BLOCKS
    streams = min(streams, traced)
    states = walk_and_estimator_states(seed, np.arange(streams))
    # A pilot of the first stream's first photons on the CPU sizes the records; too few rows, and
    # the kernel runs again with as many as it counted (the same streams make the same records).
    probe = min(PILOT_PHOTONS, traced)
    bins = optics.bins
    pilot = _white_block(mus, optics.g, optics.n, optics.depth, optics.reach, probe, 0, seed, 0, np.zeros(0, np.int32),
                         np.zeros(0, np.float32), np.zeros((0, bins), np.float32), np.zeros(0, np.int32))
    capacity = int(1.3 * pilot * traced / probe) + 1024
    device_states = cuda.to_device(states)
    threads = min(THREADS_PER_BLOCK, streams)
    while True:
        counter = cuda.to_device(np.zeros(1, np.int64))
        records = (cuda.device_array(capacity, np.int32), cuda.device_array(capacity, np.float32),
                   cuda.device_array((capacity, bins), np.float32), cuda.device_array(capacity, np.int32))
        _kernel()[-(-streams // threads), threads](
            cuda.to_device(mus), float(mus.max()), float(optics.g), float(optics.n), float(optics.depth),
            int(optics.reach), CPU.camera_constant(float(optics.n)), traced, device_states, counter, *records)
        count = int(counter.copy_to_host()[0])
        if count <= capacity:
            break
        capacity = count
    pixel, value, lengths, photon = (array.copy_to_host()[:count] for array in records)
    order = np.argsort(photon, kind="stable")
    return WhiteDatabase(optics, traced, pixel[order], value[order], lengths[order], photon[order],
                         time.perf_counter() - start)
