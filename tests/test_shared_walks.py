"""Channels that scatter alike share their walks (core/simulate/tables.py): each channel's
weight carries its own likelihood ratio, so every channel keeps its own expectation."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from ringlight.core.simulate.adding_doubling import thick_slab_reflectance
from ringlight.core.simulate.camera import optics, specular_reflectance
from ringlight.core.simulate.photon import reflectance_run, total_run
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.tables import MU_T, NULL_FACTOR_FLOOR, walk_tables
from ringlight.core.simulate.transport import channel_groups, simulate_transport


def mean_and_error(sums, squares, photons):
    mean = sums / photons
    return mean, np.sqrt(np.maximum(squares / photons - mean * mean, 0.0) / photons)


def test_tables_reduce_to_implicit_capture_for_one_channel_and_keep_null_factors_above_the_floor():
    tables, majorant = walk_tables([0.9, 0.3], [[0.1, 0.2]], [0.0, 0.5])
    assert majorant == 1.0
    np.testing.assert_allclose(tables[:, 0], [1.0, 0.9, 0.0, 1.0, 1.0])  # real: albedo; null: 1
    np.testing.assert_allclose(tables[:, 1], [0.5, 0.6, 0.5, 0.5, 1.0])
    tables, majorant = walk_tables([1.5, 0.3], [[0.01, 0.004], [0.01, 0.25], [0.012, 0.3]], [0.0, 0.0])
    nulls = tables[MU_T + 3:]
    assert nulls.min() >= NULL_FACTOR_FLOOR - 1e-12 and nulls.max() <= 1.0
    assert majorant >= (tables[MU_T:MU_T + 3]).max()


def test_shared_walks_give_each_channels_half_space_reflectance_by_adding_doubling():
    # Three channels, one walk: mua 0.02, 0.2, 1.0 against mus 1 (albedos 0.98, 0.83, 0.5).
    mus, mua, g, n = 1.0, np.array([0.02, 0.2, 1.0]), 0.5, 1.4
    tables, majorant = walk_tables([mus], mua[:, None], [g])
    photons = 100_000
    sums, squares = reflectance_run(np.zeros((1, 1, 1), np.uint8), tables, majorant, n, np.inf, photons, 5, 0)
    mean, error = mean_and_error(sums, squares, photons)
    keep = 1 - specular_reflectance(n)
    exact = thick_slab_reflectance(np.full(3, mus), mua, g, n)
    assert np.all(np.abs(mean * keep - exact) < 3 * error * keep), (mean * keep, error * keep, exact)


def test_shared_walks_match_channel_by_channel_walks_in_a_layered_medium():
    # A red layer over white clay (red-bead's materials), camera 30 degrees off the normal, so the
    # next-event estimate crosses both layers by voxel traversal: the shared walk's channels and
    # each channel walked alone agree within 3 standard errors (independent random numbers).
    volume = np.array([0, 0, 1, 1, 1, 1, 1, 1], np.uint8).reshape(-1, 1, 1)
    mus = np.array([0.3, 1.5])
    mua = np.array([[0.004, 0.01], [0.25, 0.01], [0.3, 0.012]])
    geometry = optics(1.4, 8.0, (20.0, 0.0), (30.0, 45.0), -1.0)
    photons = 60_000
    tables, majorant = walk_tables(mus, mua, [0.0, 0.0])
    shared, shared_error = mean_and_error(*total_run(volume, tables, majorant, geometry, True, photons, 1, 0), photons)
    for channel in range(3):
        alone_tables, alone_majorant = walk_tables(mus, mua[channel:channel + 1], [0.0, 0.0])
        alone, alone_error = mean_and_error(
            *total_run(volume, alone_tables, alone_majorant, geometry, True, photons, 2, channel), photons)
        gap = abs(shared[channel] - alone[0])
        assert gap < 3 * math.hypot(shared_error[channel], alone_error[0]), (channel, shared[channel], alone[0])
    assert shared[0] > 2 * shared[2]  # the red layer shows


def test_a_shared_colour_simulation_matches_one_walk_per_channel_through_both_estimators():
    # red-bead's channels scatter alike and share walks; nudging mus by 1e-9 per channel (no
    # physical change) makes every channel walk on its own, as before shared walks. Per channel,
    # the light around every lit point agrees within 4 standard errors (six seeds each). The
    # bound is in standard errors measured here, so fewer photons keep its false-alarm rate; at
    # 150 photons a seed the standard error of a difference is 0.4-0.6 % of the total: a bias over
    # 1.6-2.4 % fails (null factors taking 80 % of a channel's extra absorption: 1.9 %, fails).
    scene = load_scene("red-bead", size=(8, 8))
    apart = replace(scene, materials=tuple(
        replace(m, mus=(m.mus[0], m.mus[1] * (1 + 1e-9), m.mus[2] * (1 - 1e-9))) for m in scene.materials))
    assert channel_groups(scene) == [(0, 1, 2)] and channel_groups(apart) == [(0,), (1,), (2,)]
    for estimator in ("reference", "analogue"):
        totals = [np.array([simulate_transport(which, photons=150, seed=seed, estimator=estimator)
                            .windows.sum(axis=(0, 1, 2, 3)) for seed in range(1, 7)]) for which in (scene, apart)]
        means = [t.mean(axis=0) for t in totals]
        errors = [t.std(axis=0, ddof=1) / math.sqrt(6) for t in totals]
        assert np.all(np.abs(means[0] - means[1]) < 4 * np.hypot(*errors)), (estimator, means, errors)
        assert means[0][0] > 1.05 * means[0][2]  # the bead is red
