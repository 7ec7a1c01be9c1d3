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
_next_raw = CPU.next_raw

ESTIMATOR_STREAM = 1 << 40
"""Added to a walk's stream number to name its estimator's stream (walk streams stay below it)."""


@numba.njit(cache=True)
def _splitmix(value):
    value = value + np.uint64(0x9E3779B97F4A7C15)
    z = value
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return value, z ^ (z >> np.uint64(31))


@numba.njit(cache=True)
def seed_state(seed, stream):
    """A fresh xoroshiro128+ state (2 uint64) for ``(seed, stream)``."""
    state = np.empty(2, np.uint64)
    value = np.uint64(seed) * np.uint64(0x100000001B3) ^ np.uint64(stream)
    value, state[0] = _splitmix(value)
    value, state[1] = _splitmix(value)
    if state[0] == 0 and state[1] == 0:
        state[0] = np.uint64(1)
    return state


@numba.njit(cache=True)
def fresh_state(seeder, state):
    """Reseed ``state`` (2 uint64, in place) from the next output of ``seeder`` (advanced):
    independent streams one after another, for walks that must be replayed from their start."""
    value, state[0] = _splitmix(_next_raw(seeder))
    value, state[1] = _splitmix(value)
    if state[0] == 0 and state[1] == 0:
        state[0] = np.uint64(1)
