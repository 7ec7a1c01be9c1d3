"""The refractive index and anisotropy of a layer inversion: stated by the dataset (the manifest's
``sample`` key, written by the simulator), given by the user, or searched from the data; the width
the data allow (ringlight.core.inversion.limit) against independent computations; interval ends
to 0.005 in log absorption."""

from __future__ import annotations

import json
import math
from importlib.resources import files

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from ringlight.app.main import main
from ringlight.core.colour.chroma import chromaticity
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.dataset.manifest import read_manifest
from ringlight.core.dataset.sample import Sample
from ringlight.core.errors import DatasetError
from ringlight.core.inversion import fit as fit_module
from ringlight.core.inversion.fit import JOINT_CHI2, PROFILE_TOLERANCE, RELATIVE_FLOOR, fit_channels
from ringlight.core.inversion.forward import Forward, Structure
from ringlight.core.inversion.joint import ELLIPSE_CHI2
from ringlight.core.inversion.layer_colour import joined, region_contains
from ringlight.core.inversion.layers import invert
from ringlight.core.inversion.limit import (
    ExactForward,
    allowed_width,
    data_limits,
    exact_regions,
    log_absorption_covariance,
)
from ringlight.core.inversion.measured import MeasuredProfile
from ringlight.core.inversion.settings import N_GRID, InversionSettings, settings_from_text
from ringlight.core.inversion.white_mc import SlabOptics, run_white
from ringlight.core.simulate.adding_doubling import thick_slab_reflectance
from ringlight.core.simulate.samples import sample_dataset

from reference import write_dataset
from test_inversion import FINAL_PHOTONS, RADII, direct_profile


@pytest.fixture(scope="module")
def shared_cache(tmp_path_factory):
    """One user cache for this module's fits, so each white database is run once."""
    return tmp_path_factory.mktemp("index-cache")


def _manifest(tmp_path, sample):
    write_dataset(tmp_path / "d", 4, 4, {(y, x): np.ones((4, 4, 3), np.float32) for y in range(4) for x in range(4)},
                  extra={"sample": sample})
    return tmp_path / "d"


def test_a_manifest_states_its_samples_index_and_anisotropy(tmp_path):
    """FORMAT.md (revision 2026-11-26): the optional ``sample`` key, each of n and g optional."""
    assert read_manifest(_manifest(tmp_path / "a", {"n": 1.33, "g": 0.8})).sample == Sample(1.33, 0.8)
    assert read_manifest(_manifest(tmp_path / "b", {"n": 1.0})).sample == Sample(1.0, None)
    assert read_manifest(_manifest(tmp_path / "c", {})).sample == Sample()


@pytest.mark.parametrize("sample, message", [
    ({"n": 0.5}, "'sample.n' must be a refractive index in [1, 3], got 0.5"),
    ({"n": "1.4"}, "'sample.n' must be a finite number"),
    ({"g": 1.0}, "'sample.g' must be an anisotropy in (-1, 1), got 1.0"),
    ({"n": 1.4, "mus": 2}, "unknown key(s) 'mus' in sample"),
    ([1.4], "'sample' must be an object"),
])
def test_a_sample_key_that_cannot_hold_is_one_line_naming_the_manifest(tmp_path, sample, message):
    folder = _manifest(tmp_path, sample)
    with pytest.raises(DatasetError) as error:
        read_manifest(folder)
    assert str(error.value).startswith(str(folder / "dataset.json")) and message in str(error.value)
    assert "\n" not in str(error.value)


def test_a_simulated_dataset_states_its_scenes_index_and_anisotropy_and_a_reopen_keeps_them(place_sample):
    """The bundled layers3 is written by the simulator from the preset scene (n 1.3, g 0 in every
    material): its manifest's sample key says so, and so does the manifest a reopen reads back
    from the store's copy."""
    scene = json.loads(files("ringlight.resources.scenes").joinpath("layers3.json").read_text())
    anisotropies = {material.get("g", 0.0) for material in scene["materials"].values()}
    assert len(anisotropies) == 1
    place_sample("layers3")  # as sample_dataset writes it, written once for the whole run
    folder = sample_dataset("layers3")
    stated = json.loads((folder / "dataset.json").read_text())["sample"]
    assert stated == {"n": scene["n"], "g": anisotropies.pop()}
    first = open_dataset(folder)
    again = open_dataset(folder)  # from the store and its manifest copy
    assert first.manifest.sample == again.manifest.sample == Sample(scene["n"], stated["g"])


def test_settings_follow_the_dataset_where_the_user_gave_nothing():
    settings = settings_from_text("3", "", "", None, None)
    assert settings.indices == N_GRID and settings.anisotropy == 0.0
    stated = settings.for_dataset(Sample(1.3, 0.5))
    assert (stated.n, stated.g, stated.indices) == (1.3, 0.5, (1.3,))
    assert settings_from_text("3", "", "", 1.5, 0.1).for_dataset(Sample(1.3, 0.5)).n == 1.5  # the user's wins
    assert settings.for_dataset(Sample(None, None)).indices == N_GRID


@pytest.mark.parametrize("truth_n", [1.0, 1.4])
def test_the_index_is_found_from_the_data_and_the_truth_lies_in_every_region(truth_n, shared_cache, monkeypatch):
    """A two-layer slab by the direct simulator (its own walks with absorption) at index 1 or 1.4,
    fitted with its structure and scattering given and the index searched over N_GRID: the index
    chosen must be the truth's, and each layer's colour lie in its region and near the truth. The
    same profile fitted at the wrong index (1.4 for 1, 1 for 1.4) must be flagged as a misfit or
    keep its colours farther (the 0.041 xy of the issue's slab)."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    mua = [[0.3, 0.05, 0.01], [0.01, 0.03, 0.2]]
    mean, error = direct_profile([1.0, 1.0], mua, [0, 3], 0.0, truth_n, 24.0, 40_000, seed=11)
    measured = MeasuredProfile(RADII, mean, error, 1)
    searched = invert(measured, InversionSettings(2, (3,), 1.0, None, 0.0, 24.0, photons=20_000,
                                                  final_photons=FINAL_PHOTONS))
    assert f", n {truth_n:g} (chosen from" in searched.notes
    assert searched.warning is None
    truths = chromaticity(np.array([thick_slab_reflectance(np.ones(3), np.array(row), 0.0, truth_n) for row in mua]),
                          "sRGB")
    for layer, truth_xy in zip(searched.layers, truths):
        assert region_contains(layer.region, truth_xy)
        assert layer.determined and np.hypot(*(layer.xy - truth_xy)) < 0.02
    wrong = 1.4 if truth_n == 1.0 else 1.0
    assumed = invert(measured, InversionSettings(2, (3,), 1.0, wrong, 0.0, 24.0, photons=20_000,
                                                 final_photons=FINAL_PHOTONS))
    assumed_error = np.hypot(*(assumed.layers[0].xy - truths[0]))
    assert assumed.warning is not None or assumed_error > np.hypot(*(searched.layers[0].xy - truths[0]))


def test_a_scattering_between_the_grids_values_is_refined_to_it(shared_cache, monkeypatch):
    """A homogeneous slab of scattering 0.7 per grid step (between MUS_GRID's 0.5 and 1) by the
    direct simulator, its scattering searched: the search refines it between the grid's values to
    within 2^(1/8) of 0.7 (REFINE_STEPS), and the colour lies in its region, within 0.01 of the truth
    (adding-doubling's thick-slab colour)."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    mua = [[0.02, 0.08, 0.25]]
    mean, error = direct_profile([0.7], mua, [0], 0.0, 1.0, 24.0, 40_000, seed=5)
    inversion = invert(MeasuredProfile(RADII, mean, error, 1), InversionSettings(1, (), None, 1.0, 0.0, 24.0,
                                                                                 photons=20_000, final_photons=20_000))
    layer = inversion.layers[0]
    assert abs(math.log(layer.mus / 0.7)) <= math.log(2) / 8 + 1e-9, inversion.notes
    truth = chromaticity(thick_slab_reflectance(np.full(3, 0.7), np.array(mua[0]), 0.0, 1.0), "sRGB")
    assert region_contains(layer.region, truth) and np.hypot(*(layer.xy - truth)) < 0.01


def _forward():
    optics = SlabOptics((1.0,) * 5, 0.0, 1.3, 16.0, 13)
    return Forward(run_white(optics, 8000, seed=4), Structure((0, 2)), np.arange(0.0, 8.0))


@pytest.mark.parametrize("correlation", [0.0, 0.9])
def test_the_data_limits_covariance_is_the_inverse_fisher_matrix_by_finite_differences(correlation):
    """The Fisher matrix built here from finite differences of the forward model (not its
    analytic derivatives) and the noise model written out per ring: relative measured errors,
    independent between channels, plus the relative floor correlated between them."""
    forward = _forward()
    mua = np.array([[0.3, 0.02], [0.05, 0.05], [0.01, 0.2]])  # (C, L)
    measured = np.stack([forward.profile(row) for row in mua], axis=1)
    error = 0.004 * measured
    used = np.array([8, 8, 6])
    covariance = log_absorption_covariance(forward, mua, measured, error, used, correlation)

    def log_profile(theta):  # (R, C)
        return np.log(np.stack([forward.profile(np.exp(row)) for row in theta.reshape(3, 2)], axis=1))

    theta = np.log(mua).ravel()
    step = 1e-5
    jacobian = np.stack([(log_profile(theta + step * e) - log_profile(theta - step * e)) / (2 * step)
                         for e in np.eye(6)], axis=-1)  # (R, C, 6)
    fisher = np.zeros((6, 6))
    for r in range(8):
        active = [c for c in range(3) if r < used[c]]
        noise = np.diag(0.004 ** 2 * np.ones(len(active))) + RELATIVE_FLOOR ** 2 * np.where(
            np.eye(len(active), dtype=bool), 1.0, correlation)
        block = jacobian[r, active]
        fisher += block.T @ np.linalg.inv(noise) @ block
    np.testing.assert_allclose(covariance, np.linalg.inv(fisher), rtol=2e-3)


def test_a_channel_without_enough_rings_has_no_finite_limit_and_its_layer_no_finite_width():
    forward = _forward()
    mua = np.array([[0.3, 0.02], [0.05, 0.05], [0.01, 0.2]])
    measured = np.stack([forward.profile(row) for row in mua], axis=1)
    covariance = log_absorption_covariance(forward, mua, measured, 0.004 * measured, np.array([8, 2, 8]))
    assert np.all(np.isinf(covariance[2:4])) and np.all(np.isfinite(covariance[np.ix_([0, 1, 4, 5], [0, 1, 4, 5])]))
    optics = forward.database.optics
    assert math.isinf(allowed_width(covariance[np.ix_([0, 2, 4], [0, 2, 4])], 1.0, mua[:, 0], optics, "sRGB"))


def test_the_allowed_width_is_the_two_sigma_extent_of_sampled_chromaticities():
    """The delta method against sampling: log absorptions drawn from the covariance, each mapped
    to its thick-slab chromaticity; the width is twice sqrt(ELLIPSE_CHI2) times the larger of the
    sampled standard deviations in x and y (small spread, so the map is nearly linear)."""
    optics = SlabOptics((1.0,), 0.0, 1.4, 16.0, 13)
    mua = np.array([0.2, 0.05, 0.02])
    covariance = np.array([[4.0, 1.0, 0.5], [1.0, 2.0, 0.3], [0.5, 0.3, 3.0]]) * 1e-4
    rng = np.random.default_rng(3)
    theta = np.log(mua) + rng.multivariate_normal(np.zeros(3), covariance, 600)
    # Adding-doubling takes channels (C,): 100 draws at a time pass as 300 channels.
    rgb = np.concatenate([thick_slab_reflectance(np.ones(part.size), np.exp(part).ravel(), 0.0, 1.4).reshape(-1, 3)
                          for part in np.split(theta, 6)])
    sampled = 2 * math.sqrt(ELLIPSE_CHI2) * chromaticity(rgb, "sRGB").std(axis=0).max()
    # 600 draws give a standard deviation to 2.9 %: 10 % is over three of those.
    assert allowed_width(covariance, 1.0, mua, optics, "sRGB") == pytest.approx(sampled, rel=0.1)


def test_an_intervals_end_is_found_to_0_005_in_log_absorption_and_errs_wide():
    """One layer whose chi-square is exactly quadratic in log absorption, (theta - c)^2 / s^2:
    the end of its interval toward either bound is c -+ s sqrt(JOINT_CHI2), found from far inside
    to within PROFILE_TOLERANCE (0.005), never narrower."""
    assert PROFILE_TOLERANCE <= 0.005
    centre, scale = math.log(0.05), 1.3
    residuals = lambda theta: np.array([(theta[0] - centre) / scale])
    jacobian = lambda theta: np.array([[1.0 / scale]])
    low, high = math.log(1e-5), math.log(10.0)
    for bound, sign in ((high, 1.0), (low, -1.0)):
        profile = fit_module._Profile(residuals, jacobian, np.array([centre]), 0, low, high)
        end = fit_module._profile_end(profile, centre, bound, 0.0)
        exact = centre + sign * scale * math.sqrt(JOINT_CHI2)
        assert 0.0 <= sign * (end - exact) <= 2 * PROFILE_TOLERANCE


def test_a_profiled_end_follows_the_valley_of_a_correlated_pair_to_its_analytic_end():
    """Two layers whose chi-square is the quadratic form (theta - c)^T A (theta - c) with strongly
    correlated parameters: the profile chi-square of theta_0 (theta_1 refitted, each refit started
    at the previous one's fit) is (theta_0 - c_0)^2 / Sigma_00 with Sigma = A^-1, so its interval
    ends at c_0 -+ sqrt(JOINT_CHI2 Sigma_00) (theta_1 moves 4.8 along the valley, within its bounds)."""
    centre = np.log([0.05, 0.01])
    root = np.array([[1.0, 0.0], [1.0, 0.5]])  # A = root^T root: Sigma [[1, -2], [-2, 8]], correlation -0.71
    residuals = lambda theta: root @ (theta - centre)
    jacobian = lambda theta: root
    low, high = math.log(1e-5), math.log(10.0)
    sigma = np.linalg.inv(root.T @ root)
    for bound, sign in ((high, 1.0), (low, -1.0)):
        profile = fit_module._Profile(residuals, jacobian, centre.copy(), 0, low, high)
        end = fit_module._profile_end(profile, centre[0], bound, 0.0)
        exact = centre[0] + sign * math.sqrt(JOINT_CHI2 * sigma[0, 0])
        assert 0.0 <= sign * (end - exact) <= 2 * PROFILE_TOLERANCE


def test_an_end_sought_first_at_another_fits_end_is_still_the_analytic_end():
    """The correlated pair above, its end sought first at a hint (another fit's end of the same
    data, as the allowed-width fit takes the main fit's) 0.02 or 0.2 beyond the analytic end, or 0.2
    or 1 within it, its refits started from the unguided profile's valley: the end is still c_0 -+
    sqrt(JOINT_CHI2 Sigma_00) to PROFILE_TOLERANCE, never narrower; from a hint beyond, from fewer
    profile values than without one."""
    centre = np.log([0.05, 0.01])
    root = np.array([[1.0, 0.0], [1.0, 0.5]])
    residuals = lambda theta: root @ (theta - centre)
    jacobian = lambda theta: root
    low, high = math.log(1e-5), math.log(10.0)
    sigma = np.linalg.inv(root.T @ root)
    for bound, sign in ((high, 1.0), (low, -1.0)):
        exact = centre[0] + sign * math.sqrt(JOINT_CHI2 * sigma[0, 0])
        unguided = fit_module._Profile(residuals, jacobian, centre.copy(), 0, low, high)
        fit_module._profile_end(unguided, centre[0], bound, 0.0)
        for offset in (0.02, 0.2, -0.2, -1.0):
            profile = fit_module._Profile(residuals, jacobian, centre.copy(), 0, low, high, unguided.solved)
            end = fit_module._profile_end(profile, centre[0], bound, 0.0, hint=exact + sign * offset)
            assert 0.0 <= sign * (end - exact) <= 2 * PROFILE_TOLERANCE, (bound, offset)
            if offset > 0:
                assert len(profile.values) < len(unguided.values)


def test_the_cli_fits_at_the_datasets_index_and_reports_what_the_data_allow(tmp_path, shared_cache, monkeypatch,
                                                                              capsys, place_sample):
    """``ringlight layers --method inverse`` with no --n on layers3 (simulated at n 1.3, stated in
    its manifest): the fit is at 1.3, each layer reports the width the data allow, and a layer
    whose allowed width is beyond 0.02 is reported as not determined to that tolerance."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    place_sample("layers3")
    folder = sample_dataset("layers3")
    out = tmp_path / "fit.json"
    # What is reported, not its precision: final white runs of 20 000 photons (the default's tenth).
    assert main(["layers", str(folder), "--method", "inverse", "--boundaries", "2,5", "--mus", "0.5,0.5,1.5",
                 "--depth", "24", "--final-photons", "20000", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "n 1.3 and g 0 as the dataset states" in printed
    document = json.loads(out.read_text())
    assert ", n 1.3, g 0," in document["model"]
    for index, layer in enumerate(document["layers"]):
        width = layer["xy_width_the_data_allow"]
        assert width > 0 and layer["within_tolerance"] == (width <= 0.02)
        if width > 0.02:
            assert layer["beyond_tolerance_because"].startswith("the data allow no narrower than")
            assert f"layer {index + 1}: not determined to 0.02 xy" in printed


def test_a_region_joins_the_ellipse_the_data_allow_and_is_never_narrower_than_it():
    """The data's own two-sigma ellipse of a layer (delta method at the Fisher covariance) is as
    wide as its allowed width (a 32-gon inscribed in the ellipse: within cos(pi / 32)), and a
    region joined with it is at least that wide, while a point-like region grows to it."""
    forward = _forward()
    mua = np.array([[0.3, 0.02], [0.05, 0.05], [0.01, 0.2]])
    measured = np.stack([forward.profile(row) for row in mua], axis=1)
    xy = np.array([[0.45, 0.35], [0.25, 0.3]])
    limits = data_limits(forward, mua, measured, 0.004 * measured, np.array([8, 8, 8]), "sRGB", xy=xy)
    for k, limit in enumerate(limits):
        assert len(limit.ellipse) and np.isfinite(limit.width)
        width = np.ptp(limit.ellipse, axis=0).max()
        assert limit.width * math.cos(math.pi / 32) - 1e-12 <= width <= limit.width * (1 + 1e-9)
        np.testing.assert_allclose(limit.ellipse.mean(axis=0), xy[k], atol=1e-12)
        tiny = xy[k] + np.array([[0.0, 0.0], [1e-4, 0.0], [0.0, 1e-4]])
        assert np.ptp(joined(tiny, limit.ellipse), axis=0).max() >= width * (1 - 1e-6)  # hulls are float32


def test_the_exact_model_interval_is_where_the_data_chi_square_alone_rises_by_the_threshold():
    """The width the data allow comes from fits with the model taken as exact (no white-run
    variance): a one-layer channel's interval is where the chi-square of the data's noise alone,
    scanned on a fine grid of log absorption (brute force), rises JOINT_CHI2 above its minimum (the
    ends taken at most PROFILE_TOLERANCE outward, or at a confirmed Wald end just beyond); with the
    white run's 8000-photon noise it is wider."""
    optics = SlabOptics((1.0,) * 5, 0.0, 1.3, 16.0, 13)
    forward = Forward(run_white(optics, 8000, seed=4), Structure((0,)), np.arange(0.0, 8.0))
    clean = forward.profile(np.array([0.05]))
    error = 0.01 * clean
    measured = clean * (1.0 + 0.01 * np.random.default_rng(3).standard_normal(clean.shape))
    exact = fit_channels(ExactForward(forward), measured[:, None], error[:, None], floor=0.0)[0]
    assert exact.used == 8
    theta = np.linspace(math.log(0.05) - 0.6, math.log(0.05) + 0.6, 6001)

    def chi2(t):
        return np.sum(((np.log(measured) - np.log(forward.profile(np.exp([t])))) / (error / measured)) ** 2)

    # The fine grid's points within JOINT_CHI2 of the minimum, found without evaluating all 6001
    # (14 CPU-s): a scan of every 60th shows one valley, so they are those between the two
    # crossings of that level (to 1e-12 by root finding, the minimum by a bounded search). On
    # this profile the points are the same as the full scan's, and its minimum 1.6e-4 higher.
    coarse = np.array([chi2(t) for t in theta[::60]])
    assert np.all(np.diff(np.sign(np.diff(coarse))) >= 0)  # falls, then rises
    bottom = minimize_scalar(chi2, bounds=(theta[0], theta[-1]), method="bounded", options={"xatol": 1e-10})
    ends = [brentq(lambda t: chi2(t) - bottom.fun - JOINT_CHI2, *bracket, xtol=1e-12)
            for bracket in ((theta[0], bottom.x), (bottom.x, theta[-1]))]
    inside = theta[(theta >= ends[0]) & (theta <= ends[1])]
    low, high = np.log(exact.interval[0])
    assert inside[0] - 0.02 <= low <= inside[0] + 2e-4 and inside[-1] - 2e-4 <= high <= inside[-1] + 0.02
    noisy = fit_channels(forward, measured[:, None], error[:, None], floor=0.0)[0]
    assert np.ptp(np.log(noisy.interval[0])) > np.ptp(np.log(exact.interval[0]))


def test_the_exact_models_regions_from_the_main_fits_minima_equal_those_from_the_start_grid():
    """exact_regions guided by the main fits (started from their first-pass minima, of the same
    weights: the data's noise alone; their interval ends sought first at the main fits' and their
    refits started from the main fits' valleys) against exact_regions unguided, searching the
    start grid itself, as it did before: the same absorptions and, to 1e-4 in xy, the same regions."""
    forward = _forward()
    mua = np.array([[0.3, 0.02], [0.05, 0.05], [0.01, 0.2]])
    clean = np.stack([forward.profile(row) for row in mua], axis=1)
    measured = clean * (1.0 + 0.01 * np.random.default_rng(5).standard_normal(clean.shape))
    error = 0.01 * clean
    fits = fit_channels(forward, measured, error, floor=0.0)
    assert all(len(fit.data_minima) == fit_module.FITTED_STARTS for fit in fits)
    searched = exact_regions(forward, measured, error, "sRGB", 0.0)
    started = exact_regions(forward, measured, error, "sRGB", 0.0, fits)
    for own, lent in zip(searched, started):
        assert len(own) >= 3
        np.testing.assert_allclose(np.ptp(lent, axis=0), np.ptp(own, axis=0), atol=1e-4)
        np.testing.assert_allclose(lent.mean(axis=0), own.mean(axis=0), atol=1e-4)


def test_a_steep_profiles_end_is_found_to_0_005_in_eight_profile_values():
    """A profile chi-square that rises 10^8-fold toward the bound, exp(3 (theta - c)) - 1 (an
    opaque layer's, as layers3's red top had): its end toward the bound is c + log(1 + JOINT_CHI2)
    / 3, found to within PROFILE_TOLERANCE, never narrower, from at most 8 profile values (6 now;
    Brent's method on the chi-square itself, bracketed by the bound, asked for 12 here)."""
    centre = math.log(0.002)
    residuals = lambda theta: np.array([math.sqrt(math.expm1(3.0 * max(theta[0] - centre, 0.0)))])
    jacobian = lambda theta: np.array([[1.0]])  # unused: one layer is not refitted
    low, high = math.log(1e-5), math.log(10.0)
    profile = fit_module._Profile(residuals, jacobian, np.array([centre]), 0, low, high)
    end = fit_module._profile_end(profile, centre, high, 0.0)
    exact = centre + math.log1p(JOINT_CHI2) / 3.0
    assert 0.0 <= end - exact <= 2 * PROFILE_TOLERANCE
    assert len(profile.values) <= 8
