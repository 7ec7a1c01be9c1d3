"""Optical-property maps on homogeneous datasets made from the model's own response (the fit's
machinery: exact recovery without noise, coverage with it), from the direct simulator (the
physics), and the maps' units, edges, errors, cancel and model overlay."""

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS, model_dataset
from ringlight.core import Cancelled
from ringlight.core.optics import model_profile, optical_maps, radial
from ringlight.core.optics.maps import FIRST_RUN, OpticsError, error_freedom, t_inflation
from ringlight.core.rings.stacks import ring_stack


@pytest.fixture(scope="module")
def run():
    return radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0)


def test_noise_free_maps_recover_the_model_exactly(run):
    # The dataset is the table's own model (same run), so only interpolation separates the fit
    # from the truth: 1e-3 at most, in every channel of every pixel whose rings are whole.
    dataset = model_dataset(run, 0.5, 0.02, 20, 8)
    errors = np.full((8, 20, 20, 3), 1e-6, np.float32)  # the fit needs weights; noise-free data
    maps = optical_maps(dataset, photons=TEST_PHOTONS, errors=errors, noise_source="given")
    inside = maps.complete
    assert inside.sum() == 36  # 6 x 6 pixels lie 7.5 from every edge
    np.testing.assert_allclose(maps.musp[inside], 0.5, rtol=1e-3)
    np.testing.assert_allclose(maps.mua[inside], 0.02, rtol=1e-3)
    assert maps.determined[inside].all()
    assert maps.units == "per_grid_step" and maps.noise_source == "given" and maps.n == 1.4
    # At the corner the cut rings' members are a biased subset of distances: flagged.
    assert not maps.complete[0, 0] and abs(maps.musp[0, 0, 0] / 0.5 - 1) > 0.01


@pytest.mark.parametrize("musp, mua", [(0.5, 0.02), (0.15, 0.005)])
def test_two_sigma_intervals_cover_the_truth(run, musp, mua):
    # 5 % noise on every response value, independent: the fit's standard errors (from each
    # ring's member spread) must hold the truth within two of them in >= 93 % of the pixel
    # channels (95 % expected; 588 draws give a binomial spread of 0.9 %).
    dataset = model_dataset(run, musp, mua, 30, 8, noise=np.full(9, 0.05), seed=11)
    maps = optical_maps(dataset, photons=TEST_PHOTONS)
    inside = maps.complete
    for name, truth in (("musp", musp), ("mua", mua)):
        values, errors = getattr(maps, name)[inside], getattr(maps, f"{name}_se")[inside]
        assert np.mean(np.abs(values - truth) <= 2 * errors) >= 0.93
        assert abs(np.median(values) / truth - 1) < 0.02
    assert maps.noise_source == "ring spread"


def test_standard_errors_follow_the_noise(run):
    # Halving the noise halves the standard errors (the fit is linear at this noise).
    errors = []
    for noise in (0.04, 0.02):
        dataset = model_dataset(run, 0.5, 0.05, 22, 8, noise=np.full(9, noise), seed=3)
        maps = optical_maps(dataset, photons=TEST_PHOTONS, floor=0.0)
        errors.append(np.median(maps.musp_se[maps.complete]))
    assert errors[0] / errors[1] == pytest.approx(2.0, rel=0.1)


def test_units_are_per_mm_with_a_pitch(run):
    dataset = model_dataset(run, 0.3, 0.01, 18, 8, pitch_mm=0.1)
    errors = np.full((8, 18, 18, 3), 1e-6, np.float32)
    maps = optical_maps(dataset, photons=TEST_PHOTONS, errors=errors, noise_source="given")
    assert maps.units == "per_mm" and maps.pitch_mm == 0.1
    np.testing.assert_allclose(maps.musp[9, 9], 3.0, rtol=1e-3)  # 0.3 per grid step of 0.1 mm
    np.testing.assert_allclose(maps.mua[9, 9], 0.1, rtol=1e-3)


def test_anisotropy_scales_scattering_to_reduced_scattering():
    # g = 0.5 doubles mus for the same mus': the run's walks differ, the fit returns mus'.
    anisotropic = radial.radial_run(1.4, 0.5, TEST_PHOTONS, seed=0)
    dataset = model_dataset(anisotropic, 0.6, 0.02, 18, 8)  # mus = 0.6 per grid step, mus' 0.3
    errors = np.full((8, 18, 18, 3), 1e-6, np.float32)
    maps = optical_maps(dataset, photons=TEST_PHOTONS, errors=errors, noise_source="given")
    assert maps.g == 0.5
    np.testing.assert_allclose(maps.musp[9, 9], 0.3, rtol=1e-3)


def test_model_profile_overlays_the_pixels_ring_profile(run):
    dataset = model_dataset(run, 0.4, 0.03, 18, 8)
    radii = np.arange(8.0)
    measured = ring_stack(dataset, radii).images[:, 9, 9, 0]
    model = model_profile(0.03, 0.4, radii, n=1.4, g=0.0, photons=TEST_PHOTONS)
    np.testing.assert_allclose(model, measured, rtol=2e-3)
    # In per mm with the pitch, the same profile.
    np.testing.assert_allclose(model_profile(0.3, 4.0, radii, n=1.4, pitch_mm=0.1, photons=TEST_PHOTONS), model,
                               rtol=1e-9)


def test_cancel_stops_the_maps(run):
    dataset = model_dataset(run, 0.5, 0.02, 16, 8)
    with pytest.raises(Cancelled):
        optical_maps(dataset, photons=TEST_PHOTONS, cancelled=lambda: True)
    fractions = []
    optical_maps(dataset, photons=TEST_PHOTONS, progress=fractions.append)
    assert fractions[-1] == 1.0 and fractions == sorted(fractions)


def test_each_part_of_the_maps_is_named_and_the_fits_report_progress(run):
    """A map from a stack and its errors (the full estimator; replicates take this path too): each
    part names itself, so that the fits (their kernels compiled on a first run: 24 s at two cores
    on the skin1 sample) no longer ran under the frames' reading's name, at 60 % and silent."""
    from ringlight.core.phases import reporting_phases

    dataset = model_dataset(run, 0.5, 0.02, 16, 8)
    named, fractions = [], []
    with reporting_phases(named.append):
        optical_maps(dataset, photons=TEST_PHOTONS, estimator="full",
                     progress=lambda fraction: fractions.append((named[-1] if named else None, fraction)))
    # On a first run (numba's cache empty, as in a fresh CI clone) the fits' phase says they compile.
    named = [name.removesuffix(FIRST_RUN) for name in named]
    fractions = [(None if name is None else name.removesuffix(FIRST_RUN), fraction) for name, fraction in fractions]
    assert [name for name in named if name.startswith("the ")] == [
        "the rings and their spread", "the look-up table", "the fits"]
    fits = [fraction for name, fraction in fractions if name == "the fits"]
    assert fits and all(0.7 <= fraction <= 1.0 for fraction in fits) and fits[-1] == 1.0
    assert [fraction for _, fraction in fractions] == sorted(fraction for _, fraction in fractions)
    named.clear()
    with reporting_phases(named.append):
        optical_maps(dataset, photons=TEST_PHOTONS)  # the maps' one pass
    assert [name.removesuffix(FIRST_RUN) for name in named[-2:]] == ["the look-up table", "the rings and the fits"]


def test_the_fits_phase_says_they_compile_where_numbas_cache_lacks_their_kernel(run, monkeypatch):
    """A first run compiled the fits for about 20 s with the bar at 60 % and nothing said why."""
    from ringlight.core.optics import maps, one_pass
    from ringlight.core.phases import reporting_phases

    dataset = model_dataset(run, 0.5, 0.02, 12, 6)
    for compiled in (False, True):
        monkeypatch.setattr(maps, "fits_compiled", lambda estimator, compiled=compiled: compiled)
        monkeypatch.setattr(one_pass, "fits_compiled", lambda compiled=compiled: compiled)
        note = "" if compiled else FIRST_RUN
        named = []
        with reporting_phases(named.append):
            optical_maps(dataset, photons=TEST_PHOTONS, estimator="full")
            optical_maps(dataset, photons=TEST_PHOTONS)
        assert [name for name in named if name.startswith(("the fits", "the rings and the fits"))] == [
            "the fits" + note, "the rings and the fits" + note]


def test_missing_index_is_one_line_naming_the_dataset(run):
    dataset = model_dataset(run, 0.5, 0.02, 12, 6)
    from dataclasses import replace

    from ringlight.core.dataset.sample import Sample

    unstated = replace(dataset, manifest=replace(dataset.manifest, sample=Sample()))
    with pytest.raises(OpticsError, match=r"^synthetic.*sample\.n.*--n") as error:
        optical_maps(unstated, photons=TEST_PHOTONS)
    assert "\n" not in str(error.value)
    with pytest.raises(OpticsError, match="n must lie in"):
        optical_maps(dataset, n=0.5, photons=TEST_PHOTONS)


def test_t_inflation_of_ring_spread_errors():
    # Ring r = 1 holds 8 members at distances 1 and sqrt 2: 6 degrees of freedom, factor
    # sqrt(6 / 4); r = 0 borrows it.
    from types import SimpleNamespace

    dataset = SimpleNamespace(manifest=SimpleNamespace(replicates=()))
    freedom = error_freedom(dataset, np.arange(3.0), "ring spread")
    assert freedom.tolist() == [6.0, 6.0, 10.0]  # r = 2: 12 members at 2 and sqrt 5
    np.testing.assert_allclose(t_inflation(freedom), np.sqrt([1.5, 1.5, 10 / 8]))
