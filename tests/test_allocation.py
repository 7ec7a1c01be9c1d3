"""Neyman allocation of the correlated-difference photons (core/simulate/allocation.py)."""

from __future__ import annotations

import numpy as np
from ringlight.core.simulate.allocation import FLOOR, allocate, reach_fractions


def test_reach_fractions_average_each_point_over_its_lit_neighbours():
    rng = np.random.default_rng(3)
    grid = (5, 6)
    lit = np.array([[y, x] for y in range(5) for x in range(6) if (y, x) != (2, 2)], np.int64)
    touches = rng.integers(0, 9, len(lit))
    got = reach_fractions(touches, lit, grid, 8)
    index = {tuple(point): i for i, point in enumerate(lit)}
    for i, (y, x) in enumerate(lit):
        near = [index[(y + dy, x + dx)] for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (y + dy, x + dx) in index]
        assert got[i] == np.mean(touches[near]) / 8


def test_allocate_gives_neyman_shares_with_a_floor_at_the_cost_of_equal_shares():
    fractions = np.array([0.0, 0.001, 0.1, 0.3, 0.5, 1.0])
    photons, direct = allocate(fractions, 1000)
    # Past 0.366 a point is scored whole: variance V at cost 1 beats 2 p V at cost 1 + p.
    np.testing.assert_array_equal(direct, [False, False, False, False, True, True])
    assert 2 * 0.3 * 1.3 < 1 < 2 * 0.5 * 1.5
    cost = np.where(direct, 1, 1 + fractions)
    shares = np.where(direct, np.sqrt(0.5), np.sqrt(fractions / (1 + fractions)))
    expected = np.maximum(shares, FLOOR * shares.max())
    expected *= 1000 * (1 + fractions).sum() / (expected * cost).sum()
    np.testing.assert_array_equal(photons, np.rint(expected))
    # The expected cost is that of 1000 photons each as differences.
    assert abs((photons * cost).sum() / (1000 * (1 + fractions)).sum() - 1) < 1e-3
    assert photons[0] == photons[1] < photons[2] < photons[3] < photons[4] == photons[5]
    # Nothing reached in the pilot: every point gets the same, as a difference.
    same, none = allocate(np.zeros(3), 7)
    np.testing.assert_array_equal(same, [7, 7, 7])
    assert not none.any()
    assert allocate(np.array([0.0, 0.2]), 1)[0].min() == 1
