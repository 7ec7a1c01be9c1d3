"""The optical maps' look-up table: the white run in mean free paths, the rings' geometry
kernels and the interpolated table, against brute force and ringlight's direct simulator."""

import math

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS
from test_adding_doubling import chandrasekhar_h_at_one
from ringlight.core.optics import radial
from ringlight.core.optics.table import _class_overlaps, build_table, model_profiles, ring_kernels
from ringlight.core.rings.geometry import ring_geometry
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import simulate_transport


@pytest.fixture(scope="module")
def run():
    return radial.run_radial(1.4, 0.0, TEST_PHOTONS, seed=7)


def test_ring_kernels_tile_the_plane():
    # Unit squares displaced by any vector cover the offsets' squares exactly once: the rings
    # 0..10 (every offset within 10.5) weighted by their member counts sum to 1 wherever the
    # displaced square lies inside them (rho <= 9).
    radii = np.arange(11.0)
    kernels, step = ring_kernels(radii)
    counts = np.array([len(ring_geometry(r).offsets) for r in radii])
    rho = np.arange(kernels.shape[1]) * step
    total = counts @ kernels
    inside = rho <= 9.0
    np.testing.assert_allclose(total[inside], 1.0, atol=2e-4)


def test_square_overlap_matches_random_squares():
    # Brute force: a point uniform in the lit pixel, displaced by rho at a uniform azimuth, lands
    # in the pixel of offset (a, b) with the probability the kernel gives.
    rng = np.random.default_rng(3)
    count = 400_000
    for rho in (0.3, 1.2, 2.7):
        start = rng.random((count, 2)) - 0.5
        angle = rng.random(count) * 2 * math.pi
        end = start + rho * np.stack([np.cos(angle), np.sin(angle)], 1)
        pixel = np.floor(end + 0.5).astype(int)
        for a, b in ((0, 0), (1, 0), (1, 1), (2, 1), (3, 0)):
            # _class_overlaps takes (x offset, y offset) = (a, b) of cos, sin.
            expected = np.mean((pixel[:, 0] == a) & (pixel[:, 1] == b))
            found = _class_overlaps(np.array([[a, b]], float), np.array([rho]), 256)[0, 0]
            assert abs(found - expected) < 4 * math.sqrt(expected * (1 - expected) / count) + 2e-4


@pytest.fixture(scope="module")
def matched_run():
    return radial.run_radial(1.0, 0.0, 100_000, seed=5)


@pytest.mark.parametrize("ratio", [0.02, 0.1, 1.0])
def test_white_run_total_matches_chandrasekhars_h_function(matched_run, ratio):
    # An index-matched isotropic half-space lit and seen along the normal reflects the factor
    # omega H(1)^2 / 8 (Chandrasekhar 1960, I = F omega mu0 H(mu) H(mu0) / 4 (mu + mu0),
    # over the incident pi F mu0, times pi), omega = mus / (mus + mua): the run reweighted by
    # exp(-(mua / mus) L) over every cell.
    # Within the run's noise (0.3 % at 100 000 photons; two seeds gave +0.1 to +0.5 %).
    run = matched_run
    albedo = 1.0 / (1.0 + ratio)
    total = (run.weight * np.exp(-ratio * run.path)).sum() / run.photons
    assert total == pytest.approx(albedo * chandrasekhar_h_at_one(albedo) ** 2 / 8, rel=0.008)


def test_table_matches_the_direct_simulator(run):
    # ringlight's simulator (camera measure, reference estimator) renders a thick slab, mus 1,
    # mua 0.05 per grid step, n 1.4; its ring profile is the table's within both Monte Carlo
    # noises (a few per cent at most at these photon counts, absorbing enough to keep it low).
    mus, mua, n = 1.0, 0.05, 1.4
    half = 6
    scene = parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": 2 * half + 1, "width": 2 * half + 1},
        "depth": 40, "n": n, "materials": {"m": {"mus": [mus] * 3, "mua": [mua] * 3, "g": 0.0}},
        "background": "m", "photons_per_point": 60_000, "max_radius": half,
        "path_length_bins": {"step": 1.0, "count": 4}, "seed": 2})
    window = simulate_transport(scene, points=np.array([[half, half]])).windows[half, half, :, :, 0]
    radii = np.arange(6.0)
    simulated = np.array([np.mean([window[half + dy, half + dx] for dy, dx in ring_geometry(r).offsets])
                          for r in radii])
    table = build_table(run, radii)
    np.testing.assert_allclose(table.profile(mus, mua), simulated, rtol=0.03)
    # The Fresnel surface matters at that level: a table of n = 1.0 is off by far more.
    other = build_table(radial.run_radial(1.0, 0.0, 4000, seed=1), radii)  # noisy, but far off
    assert np.max(np.abs(other.profile(mus, mua) / simulated - 1)) > 0.1


def test_interpolated_table_matches_direct_model_between_nodes(run):
    radii = np.arange(8.0)
    table = build_table(run, radii)
    kernels, step = ring_kernels(radii)
    for musp, mua in ((0.137, 0.0031), (0.52, 0.041), (1.7, 0.23)):
        direct = model_profiles(run, kernels, step, np.array([musp]), np.array([mua / musp]))[0, 0]
        np.testing.assert_allclose(table.profile(musp, mua), direct, rtol=2e-3)


def test_profile_outside_the_table_is_nan(run):
    table = build_table(run, np.arange(4.0))
    assert np.isnan(table.profile(100.0, 0.01)).all()
    assert np.isnan(table.profile(0.1, 1e-9)).all()
    # No absorption, a negative or a non-finite value: outside too, NaN (it raised "math domain error").
    for musp, mua in ((0.1, 0.0), (0.1, -0.01), (-1.0, 0.01), (0.0, 0.01), (np.nan, 0.01), (0.1, np.inf)):
        assert np.isnan(table.profile(musp, mua)).all(), (musp, mua)
    assert np.isfinite(table.profile(0.1, 0.01)).all()


def test_cached_run_is_read_back_and_a_damaged_one_rerun(tmp_path):
    first = radial.radial_run(1.3, 0.2, 320, seed=4)
    again = radial.radial_run(1.3, 0.2, 320, seed=4)
    np.testing.assert_array_equal(first.weight, again.weight)
    path = radial.radial_path(1.3, 0.2, 320, 4)
    path.write_bytes(path.read_bytes()[:-100])  # truncated
    rerun = radial.radial_run(1.3, 0.2, 320, seed=4)
    np.testing.assert_array_equal(first.weight, rerun.weight)


def test_anisotropy_beyond_the_runs_range_is_refused():
    with pytest.raises(radial.TableError, match="g = 0.99"):
        radial.run_radial(1.4, 0.99, 10)
