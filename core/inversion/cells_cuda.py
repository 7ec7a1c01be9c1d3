"""A white run tallied into cells (:mod:`.white_cells`) on an NVIDIA GPU, as the photons are
traced: no record leaves the device.

The walk is :func:`.white_mc.compile_walk`'s, compiled as CUDA device functions; its record step
adds the estimate to its cell in a hash table on the device instead of writing a record. A cell's
key is the one :func:`.white_cells.tally_records` makes (the pixel class, then each layer's
length bin); the table finds it by linear probing from :func:`slot_of` (an atomic
compare-and-swap claims an empty slot), and atomic adds make the cell's moment sums and the
weight of its photon's batch (photon number modulo :data:`.white_cells.BATCHES`). A layer's
length is summed from the bins' lengths rounded to float32 and the value rounded to float32, as
the CPU's records hold them, so the same walks give the CPU tally's cells.

The photons run in launches of at most :data:`LAUNCH_PHOTONS` (progress between them); launch
``c`` uses seed ``seed + (c << 32)`` and, as :func:`.white_cuda.run_white_cuda`, thread ``t``
walks stream ``(seed + (c << 32), t)``. When a launch leaves the table more than half full, or
finds it full, the run starts again with a table four times as large (the same streams make the
same cells). This module imports numba's CUDA target: import it only for a CUDA run.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np
from numba import cuda, float32, float64, int64, uint64

from ..simulate.steps import CPU, cuda_steps
from ..simulate.streams import thread_share, thread_streams, walk_and_estimator_states
from .forward import Structure
from .white_cells import (_LEVELS, BATCHES, RATIO, SHORTEST, CellDatabase, cell_moments, moment_columns,
                          pixel_classes)
from .white_cuda import MOST_BINS, STREAMS, THREADS_PER_BLOCK
from .white_mc import BLOCKS, DatabaseError, SlabOptics, compile_walk

LAUNCH_PHOTONS = 1 << 20
"""Most photons a launch traces (a kernel of seconds, and progress between launches)."""
FIRST_SLOTS = 1 << 21
"""The table's first size (a three-layer structure at 10^6 photons fills about 670 000 cells)."""
MOST_LAYERS = 4
"""Layers a structure may have (:class:`.settings.InversionSettings` allows 4)."""
EMPTY = -1
"""The key of an empty slot (keys are never negative)."""
_LOG_RATIO = math.log(RATIO)
# control's entries: slots filled, records lost to a full table, the layer count, then the
# layers' first bins and the bin count.
_FILLED, _LOST, _LAYERS, _STARTS = 0, 1, 2, 3


def slot_of(key, mask):
    """The first slot probed for ``key`` (int64, >= 0) in a table of ``mask + 1`` slots (a power
    of 2): the key's bits folded and multiplied by an odd constant, within int64."""
    folded = key ^ (key >> 21) ^ (key >> 42)
    return (folded * 40503) & mask


def length_bin(length):
    """:func:`.white_cells._length_bin` of one length (grid steps)."""
    if length <= 0.0:
        return 0
    return 1 + min(int(math.log(max(length, SHORTEST) / SHORTEST) / _LOG_RATIO), _LEVELS - 2)


@functools.cache
def _kernel():
    """The CUDA kernel, compiled on first use."""
    first_slot = cuda.jit(device=True)(slot_of)
    bin_of = cuda.jit(device=True)(length_bin)

    def tally(count, control, classes, keys, sums, batches, cell, estimate, lengths, up, photon):
        layers = control[_LAYERS]
        layer_lengths = cuda.local.array(MOST_LAYERS, float64)
        key = int64(classes[cell])
        for k in range(layers):
            total = 0.0
            for b in range(control[_STARTS + k], control[_STARTS + k + 1]):
                total += float64(float32(lengths[b] + up[b]))
            layer_lengths[k] = total
            key = key * _LEVELS + bin_of(total)
        mask = keys.shape[0] - 1
        slot = first_slot(key, mask)
        found = False
        for _ in range(keys.shape[0]):
            held = cuda.atomic.cas(keys, slot, EMPTY, key)
            if held == EMPTY:
                cuda.atomic.add(control, _FILLED, 1)
                found = True
                break
            if held == key:
                found = True
                break
            slot = (slot + 1) & mask
        if not found:
            cuda.atomic.add(control, _LOST, 1)
            return count
        value = float64(float32(estimate))
        cuda.atomic.add(sums, (slot, 0), value)
        column = 1 + layers
        for k in range(layers):
            cuda.atomic.add(sums, (slot, 1 + k), value * layer_lengths[k])
            for j in range(k, layers):
                cuda.atomic.add(sums, (slot, column), value * layer_lengths[k] * layer_lengths[j])
                column += 1
        cuda.atomic.add(batches, (slot, photon % BATCHES), float32(value))
        return count + 1

    trace_photon = compile_walk(cuda.jit(device=True), cuda_steps(), cuda.jit(device=True)(tally))
    streams_of, share_of = cuda.jit(device=True)(thread_streams), cuda.jit(device=True)(thread_share)

    # The kernel is written here, not shared with white_cuda's records kernel (whose preamble it
    # repeats): numba's CUDA simulator puts its own ``cuda`` module into a module's globals only
    # while a kernel of that module runs, and ``tally`` uses cuda.atomic from this module's.
    @cuda.jit
    def cells_kernel(mus, majorant, g, n, depth, reach, constant, photons, first_photon, states, control, classes,
                     keys, sums, batches):
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
            trace_photon(state, estimator_state, mus, majorant, g, n, depth, reach, constant, lengths, up,
                         first_photon + first + p, 0, control, classes, keys, sums, batches)

    return cells_kernel


def run_cells_cuda(optics: SlabOptics, structure: Structure, photons: int, seed: int = 0, progress=None,
                   streams: int = STREAMS, slots: int = FIRST_SLOTS,
                   launch_photons: int = LAUNCH_PHOTONS) -> CellDatabase:
    """:func:`.white_cells.run_cells` on the current CUDA device: ``photons`` (rounded up to whole
    launches of whole :data:`.white_mc.BLOCKS`) shared among ``streams`` threads a launch, tallied
    in a table of ``slots`` (a power of 2, grown as needed); ``progress(fraction)`` after each
    launch (raise from it to cancel). DatabaseError for more than :data:`.white_cuda.MOST_BINS`
    depth bins or :data:`MOST_LAYERS` layers."""
    if optics.bins > MOST_BINS:
        raise DatabaseError(f"a CUDA white run takes at most {MOST_BINS} depth bins, not {optics.bins}; "
                            "use --device cpu")
    if structure.layers > MOST_LAYERS:
        raise DatabaseError(f"a CUDA white run tallies at most {MOST_LAYERS} layers, not {structure.layers}")
    start = time.perf_counter()
    launches = max(1, -(-photons // launch_photons))
    per_launch = -(-photons // (launches * BLOCKS)) * BLOCKS
    threads = min(streams, per_launch)
    layout = np.array([0, 0, structure.layers, *structure.starts, optics.bins], np.int64)
    arguments = (cuda.to_device(np.asarray(optics.mus, np.float64)), float(max(optics.mus)), float(optics.g),
                 float(optics.n), float(optics.depth), int(optics.reach), CPU.camera_constant(float(optics.n)))
    classes = cuda.to_device(pixel_classes(optics.reach))
    while True:
        control = cuda.to_device(layout)
        keys = cuda.to_device(np.full(slots, EMPTY, np.int64))
        sums = cuda.to_device(np.zeros((slots, moment_columns(structure.layers))))
        batches = cuda.to_device(np.zeros((slots, BATCHES), np.float32))
        for launch in range(launches):
            states = cuda.to_device(walk_and_estimator_states(seed + (launch << 32), np.arange(threads)))
            block = min(THREADS_PER_BLOCK, threads)
            _kernel()[-(-threads // block), block](*arguments, per_launch, launch * per_launch, states, control,
                                                   classes, keys, sums, batches)
            filled, lost = control.copy_to_host()[:2]
            if lost or 2 * filled > slots:
                break
            if progress is not None:
                progress((launch + 1) / launches)
        else:
            break
        slots *= 4
    held = keys.copy_to_host()
    order = np.argsort(held)[int(np.count_nonzero(held == EMPTY)):]
    return cell_moments(optics, structure, launches * per_launch, held[order], sums.copy_to_host()[order],
                        batches.copy_to_host()[order], time.perf_counter() - start)
