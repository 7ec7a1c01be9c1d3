"""The white run of :mod:`.radial` on an NVIDIA GPU: the same photon walk
(:func:`.radial.compile_walk`, compiled as CUDA device functions from the same statement of the
steps, :mod:`ringlight.core.simulate.steps`), one random stream per thread, the cells summed with
atomic adds.

Thread ``t`` traces its share of the photons on stream ``(seed, t)`` of the CPU's generator
(:func:`ringlight.core.simulate.streams.seed_state`), so it walks exactly the photons that the
CPU's :func:`.radial._radial_block` walks on that stream (the sums differ only in the order of
their additions). The CPU's run of the same photons uses :data:`.radial.BLOCKS` streams: a CUDA
run is another sample of it.
This module imports numba's CUDA target: import it only for a CUDA run.
"""

from __future__ import annotations

import functools
import time

import numpy as np
from numba import cuda, uint64

from ..simulate.steps import CPU, cuda_steps
from ..simulate.streams import seed_states, thread_share
from .radial import LONGEST, PATH_CELLS, RHO_CELLS, RadialRun, compile_walk, traced_photons

STREAMS = 1 << 16
"""Threads (one random stream each) of a CUDA run: enough to fill a data-centre GPU."""
THREADS_PER_BLOCK = 128


@functools.cache
def _kernel():
    """The CUDA kernel, compiled on first use."""

    def add(sums, i, j, value):
        cuda.atomic.add(sums, (i, j), value)

    trace_photon = compile_walk(cuda.jit(device=True), cuda_steps(), cuda.jit(device=True)(add))
    share_of = cuda.jit(device=True)(thread_share)

    @cuda.jit
    def radial_kernel(g, n, longest, constant, photons, states, weight, rho_sum, path_sum):
        stream = cuda.grid(1)
        streams = states.shape[0]
        if stream >= streams:
            return
        state = cuda.local.array(2, uint64)
        state[0] = states[stream, 0]
        state[1] = states[stream, 1]
        for _ in range(share_of(photons, streams, stream)[1]):
            trace_photon(state, g, n, longest, constant, weight, rho_sum, path_sum)

    return radial_kernel


def run_radial_cuda(n: float, g: float, photons: int, seed: int = 0, streams: int = STREAMS) -> RadialRun:
    """:func:`.radial.run_radial` on the current CUDA device: its photons
    (:func:`.radial.traced_photons`) shared among ``streams`` threads, the first ones one more
    each. The caller checks ``g`` and the device."""
    start = time.perf_counter()
    traced = traced_photons(photons)
    streams = min(streams, traced)
    states = cuda.to_device(seed_states(seed, np.arange(streams, dtype=np.int64)))
    sums = [cuda.to_device(np.zeros((RHO_CELLS, PATH_CELLS))) for _ in range(3)]
    threads = min(THREADS_PER_BLOCK, streams)
    _kernel()[-(-streams // threads), threads](float(g), float(n), LONGEST / (1.0 - abs(g)),
                                               CPU.camera_constant(float(n)), traced, states, *sums)
    weight, rho_sum, path_sum = (array.copy_to_host() for array in sums)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(weight > 0, rho_sum / weight, 0.0)
        path = np.where(weight > 0, path_sum / weight, 0.0)
    return RadialRun(float(n), float(g), traced, weight, rho, path, time.perf_counter() - start,
                     "cuda")
