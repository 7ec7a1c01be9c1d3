"""The layer inversion (ringlight.core.inversion): the white Monte Carlo forward model against the
direct simulator, recovery of known layers with honest uncertainty, and misfit detection."""

from __future__ import annotations

import json
from dataclasses import replace
from importlib.resources import files

import numpy as np
import pytest
from scipy.optimize import least_squares
from ringlight.app.main import main
from ringlight.core.colour.chroma import chromaticity
from ringlight.core.dataset.impulse_dataset import open_dataset
import ringlight.core.inversion.fit as fit_module
from ringlight.core.inversion.fit import JOINT_CHI2, MUA_BOUNDS, fit_channel
from ringlight.core.inversion.forward import Forward, Structure, ring_matrix
from ringlight.core.inversion.layer_colour import region_contains
from ringlight.core.inversion.layers import invert
from ringlight.core.inversion.measured import MeasuredProfile, measured_profile
from ringlight.core.inversion.report import invert_region, profile_radii
from ringlight.core.inversion.search import database_optics
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.inversion.cell_forward import CellForward
from ringlight.core.inversion.white_cells import cell_database, pixel_classes
from ringlight.core.inversion.white_mc import SlabOptics, run_white, white_database
from ringlight.core.rings.geometry import ring_geometry
from ringlight.core.simulate.adding_doubling import thick_slab_reflectance
from ringlight.core.simulate.camera import optics as scene_optics
from ringlight.core.simulate.photon import trace_events
from ringlight.core.simulate.samples import sample_dataset
from ringlight.core.simulate.tables import walk_tables

from reference import assert_slopes_are_central_differences, write_dataset

# The final white runs these tests' figures were set at (the default, 1 000 000 photons, costs CI
# a minute a fit: the evaluation tools and the docs hold its figures).
FINAL_PHOTONS = 200_000
RADII = np.arange(0.0, 10.0)
REACH = 13


_DIRECT_PROFILES = {}


def direct_profile(mus_layers, mua_layers, tops, g, n, depth, photons, seed):
    """Mean and standard error (R, 3) of the ring profile of a layered slab by the direct simulator
    (its own walks with absorption, three channels), from each photon's contribution. Simulated once
    per argument set for the session (test_inversion_finalists fits this module's two-layer slab
    too), read-only."""
    key = repr((mus_layers, mua_layers, tops, g, n, depth, photons, seed))
    if key not in _DIRECT_PROFILES:
        profile = _direct_profile(mus_layers, mua_layers, tops, g, n, depth, photons, seed)
        for array in profile:
            array.setflags(write=False)
        _DIRECT_PROFILES[key] = profile
    return _DIRECT_PROFILES[key]


def _direct_profile(mus_layers, mua_layers, tops, g, n, depth, photons, seed):
    volume = np.zeros((int(depth), 1, 1), np.uint8)
    for index, top in enumerate(tops):
        volume[top:] = index
    tables, majorant = walk_tables(np.array(mus_layers), np.array(mua_layers).T, np.full(len(tops), g))
    events = trace_events(volume, tables, majorant, scene_optics(n, depth), True, 0.0, 0.0, photons, seed, 3, 30_000_000)
    py = np.floor(events[:, 3] + 0.5).astype(int)
    px = np.floor(events[:, 4] + 0.5).astype(int)
    inside = (np.abs(py) <= REACH) & (np.abs(px) <= REACH)
    pixel = (py[inside] + REACH) * (2 * REACH + 1) + px[inside] + REACH
    photon = events[inside, 0].astype(int)
    rings = ring_matrix(RADII, REACH)
    mean = np.empty((len(RADII), 3))
    error = np.empty((len(RADII), 3))
    for c in range(3):
        for row in range(len(RADII)):
            per_photon = np.bincount(photon, events[inside, 6 + c] * rings[row, pixel], photons)
            mean[row, c] = per_photon.mean()
            error[row, c] = per_photon.std() / np.sqrt(photons)
    return mean, error


# Three layers of different scattering, forward-peaked, a Fresnel surface: every part of the model.
MUS = [0.8, 0.8, 2.0]
MUA = [[0.2, 0.02, 0.005], [0.01, 0.25, 0.03], [0.05, 0.01, 0.15]]
TOPS = [0, 2, 4]


def test_white_forward_model_equals_the_direct_simulator_within_three_standard_errors():
    optics = SlabOptics((0.8, 0.8, 0.8, 0.8, 2.0), 0.5, 1.4, 24.0, REACH)
    database = run_white(optics, 16_000, seed=3)
    forward = Forward(database, Structure((0, 2, 4)), RADII)
    direct, direct_error = direct_profile(MUS, MUA, TOPS, 0.5, 1.4, 24.0, 16_000, seed=11)
    for c in range(3):
        mua = np.array([layer[c] for layer in MUA])
        model = forward.profile(mua)
        z = (model - direct[:, c]) / np.sqrt(forward.variance(mua) + direct_error[:, c] ** 2)
        assert np.abs(z).max() < 3.0, (c, z)
        # and the profile is far from flat: the comparison has teeth
        assert model[0] / model[-1] > 100


def test_white_derivatives_match_finite_differences():
    optics = SlabOptics((1.0,) * 5, 0.0, 1.3, 16.0, REACH)
    forward = Forward(run_white(optics, 2_000, seed=1), Structure((0, 2)), RADII)
    assert_slopes_are_central_differences(forward, np.array([0.1, 0.03]))


def test_white_profile_and_slopes_are_the_records_weights_summed_over_each_ring():
    """Forward.profile from its definition, in numpy: each record of the white run weighs ``value
    exp(-lengths . mua)``, its depth bins' lengths times the absorption of the layer each bin lies
    in, summed per pixel and over each ring (ring_matrix), over the photons; the slopes the same
    sums of minus the weight times the layer's length. Three layers, the first bin-by-bin as the
    kernel's layer loop adds them."""
    optics = SlabOptics((1.0,) * 5, 0.0, 1.3, 16.0, REACH)
    starts = (0, 1, 3)
    forward = Forward(run_white(optics, 3_000, seed=5), Structure(starts), RADII)
    database = forward.database
    layer_of_bin = np.searchsorted(np.array(starts), np.arange(database.lengths.shape[1]), side="right") - 1
    lengths = database.lengths.astype(np.float64)  # stored float32: summed in float64, as the model does
    layer_lengths = np.stack([lengths[:, layer_of_bin == k].sum(axis=1) for k in range(len(starts))], axis=1)
    rings = ring_matrix(RADII, REACH)
    for mua in (np.array([0.2, 0.03, 0.01]), np.array([1e-4, 0.5, 3.0])):
        weight = database.value * np.exp(-(layer_lengths @ mua))
        per_pixel = np.zeros((len(starts) + 1, rings.shape[1]))
        for row, term in enumerate((weight, *(-weight * layer_lengths[:, k] for k in range(len(starts))))):
            np.add.at(per_pixel[row], database.pixel, term)
        expected = per_pixel @ rings.T / database.photons  # (1 + L, R)
        profile, slopes = forward.profile(mua, derivatives=True)
        np.testing.assert_allclose(profile, expected[0], rtol=1e-12)
        np.testing.assert_allclose(slopes, expected[1:].T, rtol=1e-12)
        np.testing.assert_array_equal(forward.profile(mua), profile)


@pytest.fixture(scope="module")
def shared_cache(tmp_path_factory):
    """One user cache for this module's dataset tests, so the white database is run once."""
    return tmp_path_factory.mktemp("inversion-cache")


@pytest.fixture(scope="module")
def layers3_sample(shared_cache, place_sample):
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
        place_sample("layers3")  # written once for the whole run
        return sample_dataset("layers3")


LAYERS3 = InversionSettings(boundaries=(2, 5), mus=(0.5, 0.5, 1.5), n=1.3, g=0.0, depth=24.0, photons=20_000,
                            final_photons=FINAL_PHOTONS)


def test_layers3_sample_top_and_middle_recovered_base_honestly_undetermined(layers3_sample, shared_cache, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    dataset = open_dataset(layers3_sample)
    result = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels", LAYERS3)
    inversion = result.inversion
    assert inversion.warning is None and inversion.chi2 < 2 * inversion.dof
    top, middle, base = inversion.layers
    # Measured here: top 0.034, middle 0.055 xy, inside regions 0.06 and 0.13 wide, where the data
    # (8 replicates) allow about 0.07 each: the thin, weakly scattering top layers' albedo is close
    # to 1, so the profile pins their colour only to a few hundredths (0.007 and 0.037 with the
    # 20 000-photon records of the white run alone, by the luck of their noise: 0.017 and 0.049 with
    # 200 000 photons of records).
    assert top.determined and middle.determined and "channels fitted together" in inversion.notes
    assert result.errors[0] < 0.05 and result.errors[1] < 0.08
    assert result.errors[0] < top.region_width and result.errors[1] < middle.region_width
    # The base's green is absorbed by the magenta layer above: no bound from the data.
    assert not base.determined and "G" in base.reason
    assert all(result.inside), result.errors
    # The region is what the thick-slab colours of the interval's corners span.
    corner = thick_slab_reflectance(np.full(3, 0.5), top.mua_interval[:, 0], 0.0, 1.3)
    assert region_contains(top.region, chromaticity(corner, dataset.colorspace) + 0.0)


def test_every_absorption_that_fits_as_well_lies_in_its_interval(layers3_sample, shared_cache, monkeypatch):
    """layers3's red channel: its middle and base layers can trade absorption (a curved valley of
    chi-square, where a Fisher interval once left out the truth). Brute force: along the middle's
    log absorption, the others refitted by least squares from two starts; every value whose
    chi-square is within JOINT_CHI2 of the fit's minimum must lie in the reported interval.
    A small noise floor and more white photons narrow the valley, as where it failed.

    The refits take the model's own derivatives (checked against central differences by
    test_white_derivatives_match_finite_differences), not least squares' finite differences: the
    same ten minima to 1e-8 in chi-square, in 219 model evaluations instead of 676 (half the
    brute force's CPU). The Jacobian only steers the refits; the chi-square they minimise is
    the residuals' below, independent of the fit's profile likelihood."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    monkeypatch.setattr(fit_module, "RELATIVE_FLOOR", 0.001)
    dataset = open_dataset(layers3_sample)
    measured = measured_profile(dataset, np.ones(dataset.grid_shape, bool), profile_radii(dataset))
    database = white_database(database_optics(LAYERS3, LAYERS3.mus), 60_000)
    forward = Forward(database, Structure((0, 2, 5)), measured.radii, ring_weights=measured.ring_weights)
    fit = fit_channel(forward, measured.mean[:, 0], measured.standard_error[:, 0])
    used = fit.used
    target = np.log(measured.mean[:used, 0])
    relative = fit.sigma[:used] / measured.mean[:used, 0]

    evaluated = {}

    def model(theta):
        """The residuals (used,) at ``theta`` and their slopes d/d theta (used, 3), where
        d log E / d log mua_k = mua_k dE/dmua_k / E: one evaluation for both, as least squares
        asks for them in turn at each point."""
        key = theta.tobytes()
        if key not in evaluated:
            evaluated.clear()
            profile, slopes = forward.profile(np.exp(theta), derivatives=True)
            evaluated[key] = ((target - np.log(profile[:used])) / relative,
                              -(slopes[:used] * np.exp(theta)) / profile[:used, None] / relative[:, None])
        return evaluated[key]

    low, high = np.log(MUA_BOUNDS)
    inside_values = 0
    k, others = 1, [0, 2]  # the middle layer, whose interval left out values that fit as well
    for value in np.linspace(low, high, 10):
        def held(free):
            theta = np.empty(3)
            theta[k], theta[others] = value, free
            return theta
        best = min(least_squares(lambda free: model(held(free))[0], start,
                                 jac=lambda free: model(held(free))[1][:, others], bounds=(low, high)).cost
                   for start in (np.log(fit.mua[others]), np.full(2, np.log(0.05))))
        if 2 * best - fit.chi2 < 0.95 * JOINT_CHI2:
            inside_values += 1
            assert fit.interval[k, 0] <= np.exp(value) <= fit.interval[k, 1], (np.exp(value), fit.interval[k])
    assert fit.chi2 <= np.sum(model(np.log(fit.mua))[0] ** 2) + 1e-6
    assert inside_values >= 3  # the scan did find values that fit as well


# layers-mus's red channel as tools/evaluate_inversion.py measured it (24 x 24, every point lit and
# its region mean over all of them, 4000 photons per point): E(r) and its standard error, r = 0..11.
LAYERS_MUS_RED = [0.09493716806173325, 0.011143683470975331, 0.0048064796361523, 0.0027699676782174856,
                  0.0016047226918513115, 0.000938734326889376, 0.0005993710467902687, 0.00038344446326919003,
                  0.0002531878414288412, 0.00016008642728511372, 0.00010059595333159338, 6.789802762960411e-05]
LAYERS_MUS_RED_SE = [0.0, 7.596847551600391e-06, 1.2082458148901998e-06, 7.136703463355016e-07,
                     4.6836621300215144e-07, 1.6782574245577723e-07, 1.1810487591440449e-07, 6.749907294471349e-08,
                     5.782022698001701e-08, 3.125506286227232e-08, 1.5713448953584144e-08, 1.4292250663062736e-08]


def edge_ring_weights(height, width, radii, reach):
    """(R, 2 reach + 1, 2 reach + 1) by the definition: for every point of the grid, each ring's
    members inside it, renormalised; averaged over the points."""
    weights = np.zeros((len(radii), 2 * reach + 1, 2 * reach + 1))
    for row, radius in enumerate(radii):
        ring = ring_geometry(float(radius))
        for y in range(height):
            for x in range(width):
                inside = [(dy, dx, w) for (dy, dx), w in zip(ring.offsets, ring.weights)
                          if 0 <= y + dy < height and 0 <= x + dx < width]
                total = sum(w for _, _, w in inside)
                for dy, dx, w in inside:
                    weights[row, dy + reach, dx + reach] += w / total
        weights[row] /= height * width
    return weights


def test_the_noise_weighted_pass_leaves_a_false_minimum(shared_cache, monkeypatch):
    """The fit's second pass (weighted by the white run's noise at the first) once went on from the
    first pass's best only, and stayed in a false minimum on layers-mus's red channel: mua (0.038,
    0.021) at chi-square 24.8, against 11.2 at the truth (0.005, 0.1). It must reach at least as low
    as the truth, and there."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    settings = InversionSettings(2, (2,), (0.5, 2.0), 1.4, 0.0, 24.0, photons=20_000, final_photons=FINAL_PHOTONS)
    database = white_database(database_optics(settings, settings.mus), settings.photons)
    radii = np.arange(12.0)
    forward = Forward(database, Structure((0, 2)), radii, ring_weights=edge_ring_weights(24, 24, radii, 12))
    measured, error = np.array(LAYERS_MUS_RED), np.array(LAYERS_MUS_RED_SE)
    fit = fit_channel(forward, measured, error)
    relative = fit.sigma[:fit.used] / measured[:fit.used]
    truth = np.array([0.005, 0.1])
    at_truth = np.sum((np.log(measured[:fit.used] / forward.profile(truth)[:fit.used]) / relative) ** 2)
    assert fit.chi2 <= at_truth + 1e-6, (fit.mua, fit.chi2, at_truth)
    np.testing.assert_allclose(fit.mua, truth, rtol=0.6)


def test_a_wrong_scattering_coefficient_is_caught_by_chi_square(layers3_sample, shared_cache, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    dataset = open_dataset(layers3_sample)
    # Final white runs of 20 000 photons (the default's tenth): their larger noise only lowers the
    # chi-square of the wrong model, so what is caught here is caught at the default too.
    wrong = InversionSettings(boundaries=(2, 5), mus=1.0, n=1.3, g=0.0, depth=24.0, photons=20_000,
                              final_photons=20_000)
    inversion = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels", wrong).inversion
    assert inversion.chi2 > 20 * inversion.dof
    assert "does not fit" in inversion.warning
    assert not any(layer.determined for layer in inversion.layers)


def test_structure_search_finds_the_boundary_of_a_two_layer_slab():
    """A profile made by the direct simulator (independent walks with absorption) of two layers of
    common scattering; the search over boundaries 1..8 must find 3, and the colours must lie in
    their regions."""
    mua = [[0.3, 0.05, 0.01], [0.01, 0.02, 0.2]]
    mean, error = direct_profile([1.0, 1.0], mua, [0, 3], 0.0, 1.4, 24.0, 30_000, seed=5)
    measured = MeasuredProfile(RADII, mean, error, 1)
    # Final white runs of 50 000 photons, not FINAL_PHOTONS: the layers' xy errors over white-run
    # seeds 0-3 at 50 000 photons are 0.001-0.006 (top) and 0.007-0.017 (base; 0.007 and 0.008 at
    # 200 000, seeds 0-1), the base's xy spreading 0.0036 in x and in y: the 0.03 bound holds with
    # more than three standard errors to spare.
    settings = InversionSettings(layers=2, mus=1.0, n=1.4, g=0.0, depth=24.0, photons=20_000,
                                 final_photons=50_000)
    inversion = invert(measured, settings)
    assert "boundaries [3] (searched)" in inversion.notes
    assert inversion.warning is None
    for layer, truth in zip(inversion.layers, mua):
        truth_xy = chromaticity(thick_slab_reflectance(np.ones(3), np.array(truth), 0.0, 1.4), "sRGB")
        assert region_contains(layer.region, truth_xy)
        if layer.determined:
            assert np.hypot(*(layer.xy - truth_xy)) < 0.03


def test_measured_profile_is_the_mean_of_each_lit_points_ring(layers3_sample):
    dataset = open_dataset(layers3_sample)
    region = np.zeros(dataset.grid_shape, bool)
    region[20:23, 20:23] = True
    profile = measured_profile(dataset, region, [0.0, 3.0])
    # brute force: the impulse image of each lit point, averaged over its ring
    expected = np.zeros((2, 3))
    for y in range(20, 23):
        for x in range(20, 23):
            image = dataset.impulse_image(y, x)
            for row, radius in enumerate((0.0, 3.0)):
                members, weights = ring_geometry(radius).around((y, x), dataset.grid_shape)
                expected[row] += (image[members[:, 0], members[:, 1]] * weights[:, None]).sum(0) / weights.sum()
    np.testing.assert_allclose(profile.mean, expected / 9, rtol=1e-5)


def test_the_profiles_ring_weights_give_its_mean_for_any_shift_invariant_response(tmp_path):
    """Every lit point of an 8 x 9 grid has the same impulse response I(d), asymmetric and steep;
    rings near the edge lose members. The mean over the region equals sum_d w_d I(d) with the
    profile's effective weights (to float32 rounding), while whole rings are off by percents at
    r = 1: the bias the weights remove."""
    height, width, radius = 8, 9, 3

    def response(dy, dx):
        """(..., 3) for offsets ``dy``, ``dx`` (...)."""
        tint = np.stack([1.0 + 0.2 * dy, np.ones_like(dy), 1.0 + 0.1 * dx], -1)
        return np.exp(-1.3 * np.hypot(dy, dx))[..., None] * tint + 1e-3

    yy, xx = np.mgrid[:height, :width].astype(float)
    impulses = {}
    for qy in range(height):
        for qx in range(width):
            image = response(yy - qy, xx - qx)
            image[np.hypot(yy - qy, xx - qx) > radius] = 0.0
            impulses[(qy, qx)] = image.astype(np.float32)
    write_dataset(tmp_path / "ds", height, width, impulses, max_radius=radius)
    dataset = open_dataset(tmp_path / "ds")
    radii = [0.0, 1.0, 2.0]
    profile = measured_profile(dataset, np.ones((height, width), bool), radii)
    side = profile.ring_weights.shape[1]
    half = side // 2
    dy, dx = np.mgrid[-half:half + 1, -half:half + 1].astype(float)
    values = response(dy, dx).reshape(-1, 3)
    np.testing.assert_allclose(profile.ring_weights.sum(axis=(1, 2)), 1.0)
    np.testing.assert_allclose(profile.ring_weights.reshape(len(radii), -1) @ values, profile.mean, rtol=1e-5)
    whole = ring_matrix(radii, half) @ values
    assert np.abs(whole[1] / profile.mean[1] - 1).max() > 0.01


def test_cli_inverse_writes_json_with_uncertainty_and_refuses_bad_settings_before_loading(
        layers3_sample, shared_cache, monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    out = tmp_path / "layers.json"
    # What the command writes, not the fit's precision: final white runs of 20 000 photons.
    assert main(["layers", str(layers3_sample), "--method", "inverse", "--boundaries", "2,5", "--mus", "0.5,0.5,1.5",
                 "--n", "1.3", "--depth", "24", "--final-photons", "20000", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "NOT DETERMINED" in printed and "absorption in G" in printed
    document = json.loads(out.read_text())
    assert document["method"] == "inverse"
    assert [layer["determined"] for layer in document["layers"]] == [True, True, False]
    assert all(layer["truth_in_region"] for layer in document["layers"])
    assert len(document["layers"][0]["xy_two_sigma_region"]) >= 3
    assert document["fit"]["dof"] == 27
    # Bad settings: one line, before the dataset is opened (a missing dataset would say otherwise).
    assert main(["layers", str(tmp_path / "missing"), "--method", "inverse", "--boundaries", "5,2"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "boundaries must increase" in error[0]
    assert main(["layers", str(tmp_path / "missing"), "--method", "inverse", "--mus", "1,2"]) == 2
    assert "needs the layer boundaries" in capsys.readouterr().err


def test_the_fit_finds_a_strongly_absorbing_top_over_a_clear_base_not_the_mirror_minimum():
    """layers-mus's blue channel: an absorbing skin (0.25) over a clear, strongly scattering base
    (0.005). A fit started only from equal absorptions settled in a false minimum (top 0.05, base
    opaque; chi-square 1900 against 70 at the truth); the start grid must find the truth."""
    mua = [[0.005, 0.2, 0.25], [0.1, 0.03, 0.005]]
    mean, error = direct_profile([0.5, 2.0], mua, [0, 2], 0.0, 1.4, 24.0, 20_000, seed=7)
    settings = InversionSettings(2, (2,), (0.5, 2.0), 1.4, 0.0, 24.0, photons=20_000, final_photons=FINAL_PHOTONS)
    inversion = invert(MeasuredProfile(RADII, mean, error, 1), settings)
    top, base = inversion.layers
    np.testing.assert_allclose(top.mua, mua[0], rtol=0.1, atol=0.005)
    assert base.mua[2] < 0.02
    assert inversion.warning is None
    for layer, truth in zip(inversion.layers, mua):
        for c in range(3):
            low, high = layer.mua_interval[c]
            assert low <= truth[c] <= high, (layer.mua_interval, truth)


def test_a_searched_scattering_finds_a_base_that_scatters_otherwise(shared_cache, monkeypatch):
    """layers-mus's slab (2 steps of a weakly scattering red skin, mus 0.5, over a pale blue base
    scattering four times as much) by the direct simulator. With no scattering given, the search
    must find the boundary and both scatterings (a base of its own scattering: every pair of
    MUS_GRID), fit (chi-square) and hold the truth in each layer's region. One common scattering,
    the only model searched before, does not fit this slab at all (its chi-square is asserted
    below)."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    mua = [[0.005, 0.2, 0.25], [0.1, 0.03, 0.005]]
    mean, error = direct_profile([0.5, 2.0], mua, [0, 2], 0.0, 1.4, 24.0, 20_000, seed=7)
    measured = MeasuredProfile(RADII, mean, error, 1)
    # Final white runs of 100 000 photons, not FINAL_PHOTONS. The top layer's xy error over white-run
    # seeds: 0.018-0.023 at 200 000 photons (seeds 0-3), 0.013-0.023 at 100 000 (0-2), 0.011-0.023
    # at 50 000 (0-5); about 0.02 of it is this profile's own noise, the same at any count. Its x
    # spreads, scaled to 100 000 photons by 1/sqrt(photons) and pooled, give a standard error of 0.0038
    # there: the 0.03 bound holds with about three of them to spare (0.013 at seed 0, the one run
    # here). The base's error is 0.002-0.005 at every count.
    searched = invert(measured, InversionSettings(layers=2, n=1.4, g=0.0, depth=24.0, photons=10_000,
                                                  final_photons=100_000))
    assert "boundaries [2] (searched), mus 0.5, 2 (chosen from" in searched.notes
    assert searched.warning is None
    for layer, truth, mus in zip(searched.layers, mua, (0.5, 2.0)):
        truth_xy = chromaticity(thick_slab_reflectance(np.full(3, mus), np.array(truth), 0.0, 1.4), "sRGB")
        assert region_contains(layer.region, truth_xy)
        assert layer.determined and np.hypot(*(layer.xy - truth_xy)) < 0.03
    # Final white runs of 20 000 photons for the misfit, as in test_a_wrong_scattering_...: their
    # larger noise only lowers a wrong model's chi-square (measured: 575 for 24 dof, 933 at 200 000).
    common = invert(measured, InversionSettings(layers=2, mus=1.0, n=1.4, g=0.0, depth=24.0, photons=10_000,
                                                final_photons=20_000))
    assert common.chi2 > 10 * common.dof and "does not fit" in common.warning


def test_a_capture_of_large_max_radius_is_fitted_on_the_rings_a_white_database_holds(shared_cache, tmp_path,
                                                                                        monkeypatch):
    """A paper-scale capture has rings beyond the 13 pixels a white database keeps (max_radius 24):
    its profile stops at r = 13 and the fit recovers the scene's layers as a small capture's would
    (it raised a ValueError traceback before). layers3 at max_radius 18, 24 x 24, 1000 photons a
    point, by the direct simulator; truth: FORMAT.md's thick-slab colours of the scene's layers."""
    from ringlight.core.inversion.settings import InversionError
    from ringlight.core.simulate.presets import load_scene
    from ringlight.core.simulate.transport import simulate_transport, write_transport

    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    document = json.loads((files("ringlight.resources") / "scenes" / "layers3.json").read_text())
    document.update(max_radius=18, photons_per_point=1000)
    (tmp_path / "scene.json").write_text(json.dumps(document))
    scene = load_scene(str(tmp_path / "scene.json"), size=(24, 24))
    write_transport(simulate_transport(scene, scene.photons_per_point), tmp_path / "wide")
    dataset = open_dataset(tmp_path / "wide")
    assert dataset.max_radius == 18
    np.testing.assert_array_equal(profile_radii(dataset), np.arange(14.0))
    # The rings a database holds, not the fit's precision: final white runs of 20 000 photons.
    result = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels",
                           replace(LAYERS3, final_photons=20_000))
    inversion = result.inversion
    assert inversion.warning is None and inversion.used.max() <= 14
    assert all(result.inside), result.errors
    # measured 0.041 (0.020 with a final white run of 20 000 photons) in a region 0.10 wide
    assert result.errors[0] < min(0.05, inversion.layers[0].region_width), result.errors
    # A profile measured further out than a database keeps is refused with one line, not a traceback.
    wider = measured_profile(dataset, np.ones(dataset.grid_shape, bool), np.arange(15.0))
    with pytest.raises(InversionError, match="beyond the 13 pixels"):
        invert(wider, LAYERS3)
    # So is a region of fewer than two lit points, naming the dataset.
    single = np.zeros(dataset.grid_shape, bool)
    single[np.argwhere(dataset.lit)[0][0], np.argwhere(dataset.lit)[0][1]] = True
    with pytest.raises(InversionError, match=f"{dataset.path}: the region holds 1 lit point"):
        measured_profile(dataset, single, np.arange(3.0))


@pytest.mark.parametrize(("changes", "message"), [
    ({"mus": float("nan")}, "scattering coefficients must be > 0 and at most 100 per grid step, got nan"),
    ({"mus": float("inf")}, "scattering coefficients must be > 0 and at most 100 per grid step, got inf"),
    ({"mus": 101.0}, "at most 100 per grid step, got 101"),
    ({"mus": [0.5, 1.0]}, "mus must be one number or a tuple"),
    ({"boundaries": (2.5,)}, "boundaries must be whole grid steps"),
    ({"boundaries": (1, 2, 3, 4)}, "at most 4 layers \\(3 boundaries\\), got 4 boundaries"),
    ({"photons": 0}, "photons must be 1000 to 1000000, got 0"),
    ({"photons": 10**9}, "photons must be 1000 to 1000000, got 1000000000"),
])
def test_settings_that_cannot_work_are_refused_by_their_check(changes, message):
    """A NaN scattering passed the check and divided by zero in the white run, an infinite one never
    finished, a billion photons asked for 17 GB, a list or a fractional boundary gave TypeErrors; five layers (boundaries
    given, layers not) would reach the cells' kernel, which holds four."""
    from dataclasses import replace

    from ringlight.core.inversion.settings import InversionError

    with pytest.raises(InversionError, match=message):
        replace(InversionSettings(boundaries=(2,), mus=1.0), **changes).check()


def test_a_boundary_deeper_than_a_search_reaches_is_fitted_with_a_common_scattering():
    """Two layers of one scattering meeting 10 grid steps down (a search stops at 8; given, it gave an
    IndexError): the white database gets a bin a step down to the boundary, and the fit of the
    direct simulator's profile holds the truth in each layer's region and finds the top's colour."""
    mua = [[0.02, 0.1, 0.3], [0.3, 0.05, 0.01]]
    mean, error = direct_profile([1.0, 1.0], mua, [0, 10], 0.0, 1.4, 24.0, 20_000, seed=9)
    settings = InversionSettings(boundaries=(10,), mus=1.0, n=1.4, g=0.0, depth=24.0, photons=10_000,
                                 final_photons=FINAL_PHOTONS)
    assert database_optics(settings, 1.0).bins == 11
    inversion = invert(MeasuredProfile(RADII, mean, error, 1), settings)
    assert inversion.warning is None
    for layer, truth in zip(inversion.layers, mua):
        truth_xy = chromaticity(thick_slab_reflectance(np.ones(3), np.array(truth), 0.0, 1.4), "sRGB")
        assert region_contains(layer.region, truth_xy)
    top_xy = chromaticity(thick_slab_reflectance(np.ones(3), np.array(mua[0]), 0.0, 1.4), "sRGB")
    assert np.hypot(*(inversion.layers[0].xy - top_xy)) < 0.03


def test_rings_no_white_photon_reaches_and_an_underflowing_model_do_not_stop_a_fit(layers3_sample, shared_cache,
                                                                                   monkeypatch):
    """A strongly scattering model: its white run's photons never reach the outer rings (the model
    is 0 there), and at the absorption bound the model underflows to 0; the log of 0 stopped the
    fit with a ValueError (a math domain error in the Layers tab). Now those rings are left out
    (counted against a brute-force search of the records) and the misfit is reported."""
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    dataset = open_dataset(layers3_sample)
    radii = profile_radii(dataset)
    settings = InversionSettings(boundaries=(2, 5), mus=100.0, n=1.3, g=0.0, depth=24.0, photons=1000,
                                 final_photons=1000)
    database = white_database(database_optics(settings, 100.0), 1000)
    rings = ring_matrix(radii, database.optics.reach)
    reached = [bool((rings[row, database.pixel] > 0).any()) for row in range(len(radii))]
    expected = reached.index(False) if False in reached else len(radii)
    forward = Forward(database, Structure((0, 2, 5)), radii)
    assert forward.reached == expected < len(radii)
    # The final fit's own white run, in cells: the rings holding a pixel of a class some cell has.
    cells = cell_database(database_optics(settings, 100.0), Structure((0, 2, 5)), 1000)
    lit = np.isin(pixel_classes(database.optics.reach), cells.cell_class)
    reached = [bool((rings[row] * lit > 0).any()) for row in range(len(radii))]
    expected = reached.index(False) if False in reached else len(radii)
    assert CellForward(cells, Structure((0, 2, 5)), radii).reached == expected < len(radii)
    inversion = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels", settings).inversion
    assert inversion.used.max() <= expected
    assert "does not fit" in inversion.warning and not any(layer.determined for layer in inversion.layers)


def test_a_known_structure_fit_makes_no_search_database(layers3_sample, shared_cache, monkeypatch):
    """Structure, scattering and index given: nothing is compared, so the search's white database
    (14-43 MB read for nothing) is not made; the fit's own cells are, and its notes do not speak of
    a search."""
    import ringlight.core.inversion.layers as layers_module

    def refused(*args, **kwargs):
        raise AssertionError("a known-structure fit made a search's white database")

    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(shared_cache))
    monkeypatch.setattr(layers_module, "white_database", refused)
    dataset = open_dataset(layers3_sample)
    inversion = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels",
                              replace(LAYERS3, final_photons=20_000)).inversion
    assert len(inversion.layers) == 3 and "white photons on " in inversion.notes
    assert "the search's" not in inversion.notes


def test_a_profile_of_no_more_rings_than_layers_is_refused_before_fitting():
    from ringlight.core.inversion.settings import InversionError

    measured = MeasuredProfile(np.arange(3.0), np.ones((3, 3)), np.full((3, 3), 0.01), 2)
    with pytest.raises(InversionError, match="holds 3 ring.*fitting 3 layer"):
        invert(measured, InversionSettings(boundaries=(2, 5), mus=1.0))


def test_a_search_holds_a_quarter_of_each_white_database_not_every_database_whole(tmp_path, monkeypatch):
    """A structure search makes dozens of white databases (every scattering and base it tries) and
    held each one whole until the end: 3.0 GB of peak RSS on layers3's 24 px sample. Its quick fits
    use a quarter of each database's photons, so only that quarter is kept, and the few databases
    fitted fully are loaded again. Measured with tracemalloc against the databases' own sizes in the
    cache (np.savez writes their arrays as they are): 76 MB of peak for 278 MB of databases at 2000
    photons (370 MB when held whole)."""
    import tracemalloc

    from ringlight.core.inversion.white_cache import cache_folder

    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    mua = [[0.3, 0.05, 0.01], [0.01, 0.02, 0.2]]
    mean, error = direct_profile([1.0, 1.0], mua, [0, 3], 0.0, 1.4, 24.0, 10_000, seed=5)
    tracemalloc.start()
    try:
        # Final white runs of 20 000 photons: the peak measured is then the search's, not the
        # final runs' chunks (which hold a chunk's records, 1/16 of the run, whatever the search did).
        inversion = invert(MeasuredProfile(RADII, mean, error, 1),
                           InversionSettings(layers=2, n=1.4, g=0.0, depth=24.0, photons=1000, final_photons=20_000))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    databases = [path.stat().st_size for path in cache_folder().glob("*.npz")]
    assert len(databases) > 40 and len(inversion.layers) == 2
    assert peak < 0.5 * sum(databases), (peak, sum(databases))
