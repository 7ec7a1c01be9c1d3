"""R_d(f) from ring profiles: the rings' Hankel transform against an analytic transform, a
brute-force sum over pixels, adding-doubling's total reflectance, and the model's light beyond
the rings."""

import math

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS, model_dataset
from ringlight.core.optics import diffuse_reflectance, radial, region_optics
from ringlight.core.optics.transform import model_tail, ring_transform_weights
from ringlight.core.rings.geometry import ring_geometry
from ringlight.core.simulate.adding_doubling import thick_slab_reflectance
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import simulate_transport
from scipy.special import j0


def ring_means(image: np.ndarray, radii) -> np.ndarray:
    half = image.shape[0] // 2
    return np.array([np.mean([image[half + dy, half + dx] for dy, dx in ring_geometry(float(r)).offsets])
                     for r in radii])


def test_gaussian_matches_its_analytic_hankel_transform():
    # I(d) = exp(-|d|^2 / 2 s^2) has the continuous transform 2 pi s^2 exp(-2 pi^2 s^2 f^2);
    # sampled on pixels (s = 3: Poisson summation's aliasing is exp(-2 pi^2 s^2) ~ 0) and summed
    # ring by ring out to 7 s, the transform matches it to 0.5 % of R_d(0).
    s, half = 3.0, 22
    dy, dx = np.mgrid[-half:half + 1, -half:half + 1]
    image = np.exp(-(dy ** 2 + dx ** 2) / (2 * s * s))
    radii = np.arange(21.0)
    frequencies = np.array([0.0, 0.02, 0.05, 0.1])
    found = diffuse_reflectance(radii, ring_means(image, radii), frequencies)
    exact = 2 * math.pi * s * s * np.exp(-2 * math.pi ** 2 * s * s * frequencies ** 2)
    np.testing.assert_allclose(found, exact, atol=0.005 * exact[0])


def test_rings_transform_equals_the_brute_force_pixel_sum_for_a_radial_response():
    # Where a ring's members share a value (a function of the ring's radius), the ring sum is
    # the pixel sum sum_d I(d) J0(2 pi f |d|) exactly.
    half = 9
    radii = np.arange(9.0)
    values = np.exp(-0.4 * radii) + 0.1
    image = np.zeros((2 * half + 1, 2 * half + 1))
    for radius, value in zip(radii, values):
        for oy, ox in ring_geometry(radius).offsets:
            image[half + oy, half + ox] = value
    dy, dx = np.mgrid[-half:half + 1, -half:half + 1]
    for f in (0.0, 0.07, 0.31):
        brute = (image * j0(2 * math.pi * f * np.hypot(dy, dx))).sum()
        assert diffuse_reflectance(radii, values, [f])[0] == pytest.approx(brute, rel=1e-12)


def test_zero_frequency_weights_are_the_ring_member_counts():
    assert ring_transform_weights([0, 1, 2, 3], [0.0])[0].tolist() == [1, 8, 12, 16]


def test_exitance_sum_equals_adding_doublings_total_reflectance():
    # Simulated with measure "exitance" (all light leaving each pixel), a thick absorbing slab's
    # response summed over the rings (R_d(0)) is its total diffuse reflectance, which
    # adding-doubling gives exactly; mua is high enough that the light beyond r = 8.5 is < 1e-3.
    mus, mua, g, n, half = 1.0, 0.3, 0.0, 1.4, 9
    scene = parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": 2 * half + 1, "width": 2 * half + 1},
        "depth": 30, "n": n, "materials": {"m": {"mus": [mus] * 3, "mua": [mua] * 3, "g": g}},
        "background": "m", "photons_per_point": 100_000, "max_radius": half, "measure": "exitance",
        "path_length_bins": {"step": 1.0, "count": 4}, "seed": 4})
    window = simulate_transport(scene, points=np.array([[half, half]])).windows[half, half, :, :, 0]
    radii = np.arange(9.0)
    found = diffuse_reflectance(radii, ring_means(window, radii), [0.0])[0]
    exact = thick_slab_reflectance(mus, mua, g, n)[0]
    assert found == pytest.approx(exact, rel=0.01)


def test_model_tail_is_the_light_beyond_the_rings():
    # The whole model at f (the run's every cell) is the rings' share plus the tail; the rings'
    # share computed from the model's own per-pixel response, the tail from the run.
    run = radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0)
    mus, mua = 0.3, 0.01
    frequencies = np.array([0.0, 0.03, 0.05, 0.1])
    dataset = model_dataset(run, mus, mua, 40, 12)
    region = np.zeros((40, 40), bool)
    region[18:22, 18:22] = True
    result = region_optics(dataset, region, frequencies=frequencies, photons=TEST_PHOTONS)
    whole = ((run.weight * np.exp(-(mua / mus) * run.path))[None]
             * j0(2 * math.pi * frequencies[:, None, None] * run.rho[None] / mus)).sum(axis=(1, 2)) / run.photons
    # The rings end on pixel squares, the tail at the circle r_last + 1/2: 0.4 % at f = 0. Inside
    # the rings the data hold pixels (the beam's square and the camera's), whose transfer lowers
    # the transform as f grows (1.3 % at 0.05 and 1.5 % at 0.1 cycles per grid step).
    assert result.reflectance[0, 0] == pytest.approx(whole[0], rel=0.006)
    np.testing.assert_allclose(result.reflectance[1:, 0], whole[1:], rtol=0.02)
    # A quarter of this weakly absorbing medium's light leaves beyond the rings: it must be added.
    assert 0.2 * whole[0] < model_tail(run, mus, mua, [0.0], 11.5)[0] < 0.3 * whole[0]


def test_model_reflectance_follows_diffusion_theory_where_it_holds():
    # Far from the source and at low frequencies (f << mu_tr) the diffusion approximation with
    # the Fresnel boundary (Cuccia et al. 2009, J. Biomed. Opt. 14, 024012, Eq. 12-13) gives
    # R_d(f) / R_d(0); for mus' = 1, mua = 0.01 per grid step the model agrees within 5 %.
    run = radial.radial_run(1.0, 0.0, TEST_PHOTONS, seed=0)
    musp, mua = 1.0, 0.01
    frequencies = np.array([0.0, 0.01, 0.02, 0.04])
    model = ((run.weight * np.exp(-(mua / musp) * run.path))[None]
             * j0(2 * math.pi * frequencies[:, None, None] * run.rho[None] / musp)).sum(axis=(1, 2))
    mu_tr = mua + musp
    albedo = musp / mu_tr
    a = 1.0  # index matched: R_eff = 0, A = (1 + R_eff) / (1 - R_eff)
    mu_eff = np.sqrt(3 * mua * mu_tr + (2 * math.pi * frequencies) ** 2)
    diffusion = 3 * a * albedo / ((mu_eff / mu_tr + 1) * (mu_eff / mu_tr + 3 * a))
    np.testing.assert_allclose(model / model[0], diffusion / diffusion[0], rtol=0.05)


def test_reflectance_maps_equal_the_region_where_the_surface_is_homogeneous():
    # Each interior pixel's R_d (its rings plus its fitted medium's tail, interpolated in the
    # table) equals the region's (the mean profile's rings plus the region fit's tail).
    from ringlight.core.optics import optical_maps
    from ringlight.core.optics.transform import reflectance_maps
    from ringlight.core.rings.stacks import ring_stack

    run = radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0)
    dataset = model_dataset(run, 0.3, 0.01, 30, 8, pitch_mm=0.1)
    errors = np.full((8, 30, 30, 3), 1e-6, np.float32)
    maps = optical_maps(dataset, photons=TEST_PHOTONS, errors=errors, noise_source="given")
    images = ring_stack(dataset, maps.radii).images
    frequencies = [0.0, 0.2, 0.5]  # cycles per mm
    per_pixel = reflectance_maps(maps, images, frequencies, photons=TEST_PHOTONS)
    region = np.zeros((30, 30), bool)
    region[13:17, 13:17] = True
    result = region_optics(dataset, region, frequencies=frequencies, photons=TEST_PHOTONS)
    # The tail interpolated bilinearly on the table's grid: within 0.5 % of the direct sum.
    np.testing.assert_allclose(per_pixel[:, 15, 15], result.reflectance, rtol=5e-3)
    assert per_pixel.shape == (3, 30, 30, 3) and np.isfinite(per_pixel).all()
