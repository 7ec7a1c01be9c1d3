"""Adding-doubling slab reflectance against Chandrasekhar's H-function, published tables, the
simulator's Monte Carlo, and its own limits (energy conservation, no scattering, quadrature)."""

import math

import numpy as np
import pytest
from ringlight.core.simulate.adding_doubling import (
    fresnel_inside,
    quadrature,
    slab_reflectance_transmittance,
    thick_slab_reflectance,
)
from ringlight.core.simulate.photon import reflectance_run
from ringlight.core.simulate.tables import single_channel_tables


def chandrasekhar_h_at_one(albedo: float, nodes: int = 200) -> float:
    """H(1) for isotropic scattering, by iterating Chandrasekhar's (1960, Eq. V.39) form
    1 / H(mu) = sqrt(1 - albedo) + albedo / 2 int_0^1 mu' H(mu') / (mu + mu') dmu'.
    Gauss-Legendre in t with mu' = t^2 absorbs the kink of H at mu' = 0."""
    t, w = np.polynomial.legendre.leggauss(nodes)
    t, w = (t + 1) / 2, w / 2
    mu, weight = t**2, 2 * t * w
    h = np.ones(nodes)
    for _ in range(10_000):
        previous = h
        h = 1 / (math.sqrt(1 - albedo) + albedo / 2 * (weight * mu * h / (mu[:, None] + mu)).sum(axis=1))
        if np.abs(h - previous).max() < 1e-15:
            break
    return 1 / (math.sqrt(1 - albedo) + albedo / 2 * (weight * mu * h / (1 + mu)).sum())


def specular(n):
    return ((n - 1) / (n + 1)) ** 2


@pytest.mark.parametrize("albedo", [0.1, 0.5, 0.8, 0.9, 0.99, 0.999])
def test_matched_isotropic_half_space_is_one_minus_h_sqrt_one_minus_albedo(albedo):
    # Chandrasekhar (1960), Radiative Transfer, Sec. 47 / van de Hulst (1980), Sec. 8.3: the plane
    # albedo of a half-space under a beam at cosine mu0 is 1 - H(mu0) sqrt(1 - albedo).
    exact = 1 - chandrasekhar_h_at_one(albedo) * math.sqrt(1 - albedo)
    assert thick_slab_reflectance(albedo, 1 - albedo, 0.0, 1.0)[0] == pytest.approx(exact, abs=1e-9)


@pytest.mark.parametrize("albedo, published", [
    (0.9, 0.41495),  # the half-space value quoted in issue 18 (adding-doubling, 5 digits)
    (0.8, 0.28525),  # Prahl's iad test suite (iad.rt(1, 1, 0.8, 1e5, 0) -> UR1 = 0.28525)
])
def test_matched_isotropic_half_space_matches_published_values(albedo, published):
    assert thick_slab_reflectance(albedo, 1 - albedo, 0.0, 1.0)[0] == pytest.approx(published, abs=5e-6)


@pytest.mark.parametrize("albedo, tau, g, published_r, published_t", [
    # Prahl's iad test suite, test_04_finite and test_05_finite_anisotropic (n = 1).
    (0.8, 1.0, 0.0, 0.21085, 0.54140),
    (0.8, 1.0, 0.8, 0.03041, 0.76388),
    # van de Hulst (1980) via the MCML manual (Wang, Jacques 1992, Table 6.1): mu_a = 10/cm,
    # mu_s = 90/cm, g = 0.75, d = 0.02 cm, n = 1: R_d = 0.09739, T_t = 0.66096.
    (0.9, 2.0, 0.75, 0.09739, 0.66096),
])
def test_matched_finite_slabs_match_published_tables(albedo, tau, g, published_r, published_t):
    reflectance, transmittance = slab_reflectance_transmittance(albedo, 1 - albedo, g, 1.0, tau)
    # The tables give 5 digits: agreement to rounding.
    assert reflectance[0] == pytest.approx(published_r, abs=5e-6)
    assert transmittance[0] == pytest.approx(published_t, abs=5e-6)


def test_mismatched_half_space_matches_giovanelli():
    # Giovanelli (1955), as quoted in the MCML manual: n = 1.5, albedo 0.9, g = 0, half-space:
    # total reflectance 0.2600 with the 0.04 specular reflection. Giovanelli's 4-digit value
    # (computed in 1955) is within 1e-4 of ours (0.25992).
    total = thick_slab_reflectance(90.0, 10.0, 0.0, 1.5)[0] + specular(1.5)
    assert total == pytest.approx(0.2600, abs=1e-4)


@pytest.mark.parametrize("mus, mua, g, n", [(0.9, 0.1, 0.0, 1.5), (0.9, 0.1, 0.5, 1.4), (0.99, 0.01, 0.0, 1.33)])
def test_mismatched_half_space_matches_the_simulators_monte_carlo(mus, mua, g, n):
    photons = 200_000
    mu_t = mus + mua
    tables, majorant = single_channel_tables([mu_t], [mus / mu_t], [g])
    (total,), (squares,) = reflectance_run(np.zeros((1, 1, 1), np.uint8), tables, majorant, n, np.inf, photons, 3, 0)
    # The exitance run scores per photon that got in: per incident power, times 1 - specular.
    mean = total / photons * (1 - specular(n))
    error = math.sqrt(max(squares / photons - (total / photons) ** 2, 0.0) / photons) * (1 - specular(n))
    exact = thick_slab_reflectance(mus, mua, g, n)[0]
    assert abs(mean - exact) < 3 * error, (mean, error, exact)


@pytest.mark.parametrize("albedo, g, n, tau", [
    (0.99, 0.9, 1.4, np.inf), (0.5, 0.9, 1.6, np.inf), (0.9, 0.0, 1.5, np.inf), (0.999, -0.5, 1.33, np.inf),
    (0.9, 0.75, 1.4, 2.0), (0.99, 0.5, 1.5, 0.3),
])
def test_default_quadrature_is_converged(albedo, g, n, tau):
    # Doubling the nodes changes nothing at the accuracy the colours need (1e-4);
    # measured: at most 1.0e-6 (albedo 0.99, g 0.9, n 1.4).
    default = np.concatenate(slab_reflectance_transmittance(albedo, 1 - albedo, g, n, tau))
    fine = np.concatenate(slab_reflectance_transmittance(albedo, 1 - albedo, g, n, tau, points=96))
    np.testing.assert_allclose(default, fine, atol=5e-6)


@pytest.mark.parametrize("g, n, tau", [(0.5, 1.4, 2.0), (0.0, 1.0, 1.0), (0.9, 1.6, 5.0), (0.0, 1.5, 0.01)])
def test_non_absorbing_slab_returns_all_light_that_got_in(g, n, tau):
    reflectance, transmittance = slab_reflectance_transmittance(1.0, 0.0, g, n, tau)
    assert reflectance[0] + transmittance[0] == pytest.approx(1 - specular(n), abs=1e-9)


def test_half_space_reflectance_rises_to_all_that_got_in_as_absorption_vanishes():
    n = 1.4
    albedos = np.array([0.0, 0.5, 0.9, 0.99, 0.9999, 1 - 1e-8, 1.0])
    reflectance = thick_slab_reflectance(albedos, 1 - albedos, 0.3, n)
    assert reflectance[0] == 0.0
    assert np.all(np.diff(reflectance) > 0)
    assert reflectance[-1] == pytest.approx(1 - specular(n), abs=1e-15)
    # R = 1 - O(sqrt(1 - albedo)): within 1e-3 at 1 - albedo = 1e-8.
    assert reflectance[-2] == pytest.approx(1 - specular(n), abs=1e-3)


def test_slab_without_scattering_is_a_fresnel_window():
    n, tau = 1.4, 0.7
    r = specular(n)
    loss = math.exp(-tau)
    reflectance, transmittance = slab_reflectance_transmittance(0.0, tau, 0.0, n, 1.0)
    # The beam bounces between the faces: T = (1 - r)^2 e^-tau / (1 - r^2 e^-2tau), and what the
    # bottom face sends back leaves through the top (the top's specular part excluded).
    assert transmittance[0] == pytest.approx((1 - r) ** 2 * loss / (1 - r**2 * loss**2), abs=1e-9)
    assert reflectance[0] == pytest.approx((1 - r) ** 2 * r * loss**2 / (1 - r**2 * loss**2), abs=1e-9)
    empty_r, empty_t = slab_reflectance_transmittance(0.0, 0.0, 0.0, n, 1.0)
    assert empty_t[0] == pytest.approx((1 - r) ** 2 / (1 - r**2), abs=1e-12)
    assert empty_r[0] == pytest.approx((1 - r) ** 2 * r / (1 - r**2), abs=1e-12)
    assert thick_slab_reflectance([0.0, 0.0], [1.0, 0.0], 0.5, n).tolist() == [0.0, 0.0]


def test_channels_are_computed_as_one_at_a_time():
    mus, mua = np.array([0.74, 0.88, 1.01]), np.array([0.032, 0.17, 0.48])
    together = thick_slab_reflectance(mus, mua, 0.2, 1.4)
    alone = [thick_slab_reflectance(s, a, 0.2, 1.4)[0] for s, a in zip(mus, mua)]
    np.testing.assert_allclose(together, alone, atol=1e-13)
    # Only the albedo matters for a half-space: the length unit does not.
    np.testing.assert_allclose(thick_slab_reflectance(mus * 10, mua * 10, 0.2, 1.4), together, atol=1e-13)


@pytest.mark.parametrize("n", [1.0, 1.33, 1.6])
def test_quadrature_integrates_smooth_functions_and_ends_at_the_normal(n):
    quad = quadrature(n, 48)
    assert quad.mu[-1] == 1.0
    assert np.all(np.diff(quad.mu) > 0) and quad.mu[0] > 0
    assert (quad.weight * quad.mu**3).sum() == pytest.approx(0.25, abs=1e-13)
    # The Fresnel flux transmittance of a Lambertian field inside, 1 - 2 int_0^1 F mu dmu, is
    # 1 / n^2 of that from outside: 2 int_0^1 (1 - F) mu dmu = (1 - r_outside_hemisphere) / n^2,
    # with r_outside from the same Fresnel formula seen from air (Snell's etendue).
    inside = 2 * (quad.weight * quad.mu * (1 - fresnel_inside(n, quad.mu))).sum()
    t, w = np.polynomial.legendre.leggauss(400)
    mu_out = (t + 1) / 2
    mu_in = np.sqrt(1 - (1 - mu_out**2) / n**2)
    outside = 2 * (w / 2 * mu_out * (1 - fresnel_inside(n, mu_in))).sum()
    assert inside == pytest.approx(outside / n**2, abs=1e-8)
