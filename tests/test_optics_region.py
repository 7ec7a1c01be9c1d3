"""A region's optical properties: its mean profile's fit against the per-pixel maps and the truth,
the model's profile over it, and the two-layer option through the layer inversion."""

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS, model_dataset
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.optics import optical_maps, radial, region_optics
from ringlight.core.optics.maps import OpticsError


@pytest.fixture(scope="module")
def run():
    return radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0)


def test_region_fit_matches_the_truth_and_the_maps(run):
    dataset = model_dataset(run, 0.4, 0.03, 24, 8, noise=np.full(9, 0.03), seed=4, pitch_mm=0.2)
    region = np.zeros((24, 24), bool)
    region[8:16, 8:16] = True
    result = region_optics(dataset, region, frequencies=[0.0, 0.5], photons=TEST_PHOTONS)
    assert result.units == "per_mm" and result.points == 64
    np.testing.assert_allclose(result.musp, 2.0, rtol=0.01)  # 0.4 per grid step of 0.2 mm
    np.testing.assert_allclose(result.mua, 0.15, rtol=0.03)
    maps = optical_maps(dataset, photons=TEST_PHOTONS)
    np.testing.assert_allclose(result.musp, np.median(maps.musp[region], axis=0), rtol=0.01)
    # The fitted model lies over the measured mean profile within its noise.
    assert np.all(np.abs(result.model - result.profile) < 4 * result.profile_se + 0.01 * result.profile)
    assert result.reflectance.shape == (2, 3) and (result.reflectance[1] < result.reflectance[0]).all()


def test_whole_grid_region_fits_its_cut_rings(run):
    # The whole grid's mean profile averages rings cut by the edges: the table is built for the
    # rings as they were cut, so the fit stays on the truth (whole rings' model: off by >1 %).
    dataset = model_dataset(run, 0.4, 0.03, 14, 6)
    result = region_optics(dataset, photons=TEST_PHOTONS)
    np.testing.assert_allclose(result.musp, 0.4, rtol=2e-3)
    np.testing.assert_allclose(result.mua, 0.03, rtol=5e-3)


def test_two_layers_through_the_inversion(run):
    dataset = model_dataset(run, 0.5, 0.02, 16, 6, noise=np.full(7, 0.02), seed=2)
    settings = InversionSettings(photons=2000, final_photons=20000, depth=24)
    result = region_optics(dataset, layers=2, photons=TEST_PHOTONS, layer_settings=settings)
    inversion = result.layers
    assert len(inversion.layers) == 2
    top = inversion.layers[0]
    assert top.mus == pytest.approx(0.5, rel=0.02)  # the homogeneous fit's scattering
    np.testing.assert_allclose(top.mua, 0.02, rtol=0.25)  # small white runs: a rough top layer


def test_bad_regions_are_refused(run):
    dataset = model_dataset(run, 0.4, 0.03, 12, 6)
    with pytest.raises(OpticsError, match="mask is 3 x 3"):
        region_optics(dataset, np.ones((3, 3), bool), photons=TEST_PHOTONS)
    with pytest.raises(OpticsError, match="no lit point"):
        region_optics(dataset, np.zeros((12, 12), bool), photons=TEST_PHOTONS)
    with pytest.raises(OpticsError, match="1 or 2 layers"):
        region_optics(dataset, layers=3, photons=TEST_PHOTONS)
    # Frequencies the command line refuses were taken here: NaN gave NaN R_d, -1 that of +1, none an empty one.
    for frequencies in ([np.nan], [-1.0], [], "abc", [[0.1]], [0.1, np.inf]):
        with pytest.raises(OpticsError, match="frequencies must be one or more finite numbers >= 0"):
            region_optics(dataset, frequencies=frequencies, photons=TEST_PHOTONS)
