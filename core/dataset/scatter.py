"""The compiled scatter of a batch of frames into a band's responses (:mod:`.assembly`).

Point by point, in parallel over rows: a point's responses are one block, which a batch fills in
one visit (its light from every frame of the batch) rather than one scattered write a frame, with
the block's offsets in raster order (slots), put in the array's order (by distance) once the band
is complete (:func:`slots_to_offsets`). A band whose responses fit a core's cache is scattered
frame by frame instead (:func:`_scatter_frames`): its blocks stay cached, and the batch is read
once, in its order, where a visit a point read a cache line of every frame's marks for each of its
points (a long manifest of 10 x 10 frames: 0.8 us a frame, most of it waiting on memory). Every
point adds its frames in frame order either way, so the sums are the same, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np


def scatter(responses, steady, radiance, owner, count) -> None:
    """:func:`_scatter_frames` when the band's responses are small, else :func:`_scatter_batch` on
    every core when the batch is large, else on this thread: the threads' start and wait cost about
    15 ms of CPU a call, more than a batch of 1000 frames of 10 x 10 points takes alone. All add in
    frame order: the sums are the same, bit for bit."""
    if responses.nbytes + steady.nbytes <= CACHED_BLOCKS:
        _scatter_frames(responses, steady, radiance, owner, count)
    elif responses.shape[0] * responses.shape[1] * count < PARALLEL_SCATTER:
        _scatter_rows(responses, steady, radiance, owner, count, 0, responses.shape[0])
    else:
        _scatter_batch(responses, steady, radiance, owner, count)


PARALLEL_SCATTER = 2**22
"""Frame points (rows x W x frames) of a batch from which :func:`scatter` runs on every core."""
CACHED_BLOCKS = 2**18
"""Most bytes of a band's responses and steady state that :func:`scatter` scatters frame by frame
(within a core's second-level cache)."""


@numba.njit(cache=True, nogil=True, inline="always")
def _add_light(responses, steady, radiance, owner, b, y, x):  # pragma: no cover - compiled
    """Point [y, x]'s light in frame ``b`` of the batch added to its owner's slot and its steady state."""
    k = owner[b, y, x]
    if k >= 0:
        for c in range(3):
            light = radiance[b, y, x, c]
            responses[y, x, k, c] += light
            steady[y, x, c] += light


@numba.njit(cache=True, nogil=True)
def _scatter_frames(responses, steady, radiance, owner, count):  # pragma: no cover - compiled
    """:func:`_scatter_batch` frame by frame, on this thread: the batch read in its order."""
    rows, width = responses.shape[0], responses.shape[1]
    for b in range(count):
        for y in range(rows):
            for x in range(width):
                _add_light(responses, steady, radiance, owner, b, y, x)


@numba.njit(parallel=True, cache=True, nogil=True)
def _scatter_batch(responses, steady, radiance, owner, count):  # pragma: no cover - compiled
    """responses[p, owner[b, p]] += radiance[b, p] (weighed, the owner a slot: see :class:`.assembly._Batch`)
    for the first ``count`` frames b of a batch, in frame order, and the same into ``steady[p]``
    (float64); parallel over rows (each thread owns its points)."""
    for y in numba.prange(responses.shape[0]):
        _scatter_rows(responses, steady, radiance, owner, count, y, y + 1)


@numba.njit(cache=True, nogil=True)
def _scatter_rows(responses, steady, radiance, owner, count, row0, row1):  # pragma: no cover - compiled
    """:func:`_scatter_batch` of rows ``row0 .. row1``, on this thread."""
    width = responses.shape[1]
    for y in range(row0, row1):
        for x in range(width):
            for b in range(count):
                _add_light(responses, steady, radiance, owner, b, y, x)


def slots_to_offsets(responses, slot_of) -> None:
    """Put every point's (K, 3) block of ``responses`` from slot order into offset order in place:
    offset k is slot ``slot_of[k]``. In parallel over rows, or on this thread for a band of
    :data:`CACHED_BLOCKS` or less, where starting the threads and their wait cost more than the
    work (14 ms of CPU for a 10 x 10 grid)."""
    if responses.nbytes <= CACHED_BLOCKS:
        _offset_order_rows(responses, slot_of, 0, responses.shape[0])
    else:
        _offset_order(responses, slot_of)


@numba.njit(parallel=True, cache=True, nogil=True)
def _offset_order(responses, slot_of):  # pragma: no cover - compiled
    """:func:`slots_to_offsets` in parallel over rows."""
    for y in numba.prange(responses.shape[0]):
        _offset_order_rows(responses, slot_of, y, y + 1)


@numba.njit(cache=True, nogil=True)
def _offset_order_rows(responses, slot_of, row0, row1):  # pragma: no cover - compiled
    """:func:`slots_to_offsets` of rows ``row0 .. row1``, on this thread, one block (K x 12 bytes)
    copied at a time."""
    width, count = responses.shape[1], responses.shape[2]
    block = np.empty((count, 3), np.float32)
    for y in range(row0, row1):
        for x in range(width):
            # Copied in loops: a slice assignment made numba compile its broadcasting and the
            # strings of its errors, 10 of a fresh install's 18 s for this module's kernels (the
            # same speed: 0.025 s for 200 MB either way).
            for k in range(count):
                for c in range(3):
                    block[k, c] = responses[y, x, k, c]
            for k in range(count):
                slot = slot_of[k]
                for c in range(3):
                    responses[y, x, k, c] = block[slot, c]
