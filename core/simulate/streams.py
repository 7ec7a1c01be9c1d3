"""Random number streams for the photon kernels: xoroshiro128+ seeded by splitmix64.

A stream is named by ``(seed, stream)``; the simulator gives each lit point and channel its own
walk stream and, :data:`ESTIMATOR_STREAM` above it, its own estimator stream, so that no result
depends on how points are shared among threads.
"""

from __future__ import annotations

import numba
import numpy as np

from .steps import CPU

uniform = CPU.uniform
"""Next float in [0, 1) from a xoroshiro128+ state (advanced in place): :mod:`.steps`, compiled for the CPU."""
_seed_from = CPU.seed_from

ESTIMATOR_STREAM = 1 << 40
"""Added to a walk's stream number to name its estimator's stream (walk streams stay below it)."""


@numba.njit(cache=True)
def seed_state(seed, stream):
    """A fresh xoroshiro128+ state (2 uint64) for ``(seed, stream)``."""
    state = np.empty(2, np.uint64)
    _seed_from(np.uint64(seed) * np.uint64(0x100000001B3) ^ np.uint64(stream), state)
    return state


@numba.njit(cache=True)
def seed_states(seed, streams):
    """(n, 2) uint64: :func:`seed_state` of ``(seed, streams[i])`` in row ``i``, ``streams`` (n,)
    int64 (a GPU run's streams: a Python loop of :func:`seed_state` took 0.8 s for 20 000 streams
    and their estimator streams)."""
    states = np.empty((streams.size, 2), np.uint64)
    for i in range(streams.size):
        _seed_from(np.uint64(seed) * np.uint64(0x100000001B3) ^ np.uint64(streams[i]), states[i])
    return states


def walk_and_estimator_states(seed: int, streams: np.ndarray) -> np.ndarray:
    """(2 n, 2) uint64: the walk states of streams ``(seed, streams[i])`` in rows ``i``, then their
    estimator streams' (:data:`ESTIMATOR_STREAM` above) in rows ``n + i``."""
    streams = np.asarray(streams, np.int64)
    return np.concatenate([seed_states(seed, streams), seed_states(seed, streams + ESTIMATOR_STREAM)])


def thread_streams(states, i, count, state, estimator_state):
    """Thread ``i``'s walk state (row ``i`` of ``states``, as :func:`walk_and_estimator_states`
    stacks them for ``count`` threads) and its estimator's (row ``count + i``), copied into
    ``state`` and ``estimator_state`` (2 uint64 each). Compiled into the CUDA kernels."""
    for k in range(2):
        state[k] = states[i, k]
        estimator_state[k] = states[count + i, k]


def thread_share(photons, threads, thread):
    """``(first, count)``: thread ``thread``'s share of ``photons`` shared among ``threads``, the
    first ``photons % threads`` threads one more each, numbered from photon 0. Compiled into the
    CUDA kernels."""
    share = photons // threads
    extra = photons % threads
    return thread * share + min(thread, extra), share + (1 if thread < extra else 0)


fresh_state = CPU.fresh_state
"""``fresh_state(seeder, state)``: reseed ``state`` (2 uint64, in place) from the next output of
``seeder`` (advanced): independent streams one after another, for walks that must be replayed
from their start (:mod:`.steps`, compiled for the CPU)."""
