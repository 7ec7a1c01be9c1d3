"""The ring sums of :mod:`.stacks` on an NVIDIA GPU: a gather kernel, one thread per grid point,
that sums each ring's run of the point's responses with its weights, as
:func:`.stacks._ring_sums` does on the CPU (the members' counts and weights come from the CPU,
:func:`.members.ring_members`).

This module imports numba's CUDA target: import it only for a CUDA run.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import cuda

from .stacks import store_mean

THREADS = (8, 16)
"""Threads per block, (rows, columns) of grid points."""


@functools.cache
def _kernel():
    """The CUDA kernel, compiled on first use."""
    store = cuda.jit(device=True)(store_mean)

    @cuda.jit
    def ring_sums_kernel(responses, first, stop, weight_start, weights, counts, totals, images):
        y, x = cuda.grid(2)
        if y >= responses.shape[0] or x >= responses.shape[1]:
            return
        for j in range(first.size):
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            shift = weight_start[j] - first[j]
            for k in range(first[j], stop[j]):
                w = weights[shift + k]
                s0 += w * responses[y, x, k, 0]
                s1 += w * responses[y, x, k, 1]
                s2 += w * responses[y, x, k, 2]
            store(images, j, y, x, counts[j, y, x], totals[j, y, x], s0, s1, s2)

    return ring_sums_kernel


def cuda_ring_sums(responses, first, stop, weight_start, weights, unweighted, counts, totals, images) -> None:
    """:func:`.stacks._ring_sums` on the current CUDA device (same arguments; ``unweighted`` is not
    needed: every ring is summed with its weights). Fills ``images`` (n, rows, W, 3) float32."""
    device_images = cuda.device_array(images.shape, np.float32)
    device_ring_sums(cuda.to_device(np.ascontiguousarray(responses)), first, stop, weight_start, weights,
                     np.ascontiguousarray(counts), np.ascontiguousarray(totals), device_images)
    images[...] = device_images.copy_to_host()


def device_ring_sums(responses, first, stop, weight_start, weights, counts, totals, images) -> None:
    """The kernel's launch over ``responses`` (rows, W, K, 3) float32 and ``images`` (n, rows, W, 3)
    float32, both already on the device (the ring tables, ``counts`` and ``totals`` are copied)."""
    rows, width = responses.shape[:2]
    blocks = (-(-rows // THREADS[0]), -(-width // THREADS[1]))
    _kernel()[blocks, THREADS](responses, cuda.to_device(first), cuda.to_device(stop), cuda.to_device(weight_start),
                               cuda.to_device(weights), cuda.to_device(counts), cuda.to_device(totals), images)
