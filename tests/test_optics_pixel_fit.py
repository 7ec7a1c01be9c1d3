"""The per-pixel fits against scipy's least squares on the same table, and each fit's ring sigma
against the maps' array of them."""

import doctest
import math

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS
from ringlight.core.optics import radial
from ringlight.core.optics import ring_sigma as ring_sigma_module
from ringlight.core.optics.maps import MODEL_FLOOR
from ringlight.core.optics.pixel_fit import CONVERGED, fit_profiles
from ringlight.core.optics.ring_sigma import ring_sigma
from ringlight.core.optics.table import build_table
from scipy.optimize import least_squares

TRUTHS = [(0.5, 0.02), (0.15, 0.005), (1.2, 0.1)]  # (mus, mua) per grid step, one per channel


@pytest.fixture(scope="module")
def table():
    return build_table(radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0), np.arange(8.0))


def noisy_profiles(table, noise, seed, width=14, height=2):
    """(R, H, W, 3) profiles of TRUTHS (a channel each) with relative Gaussian ``noise``, and their sigma."""
    rng = np.random.default_rng(seed)
    truth = np.stack([table.profile(mus, mua) for mus, mua in TRUTHS], axis=-1)  # (R, 3)
    shape = (len(table.radii), height, width, 3)
    sigma = np.broadcast_to(noise * truth[:, None, None, :], shape)
    measured = truth[:, None, None, :] + sigma * rng.standard_normal(shape)
    return measured.astype(np.float32), sigma.astype(np.float32)


def scipy_fit(table, measured, sigma, start):
    """The chi2 minimum by scipy's trust-region least squares on the table's interpolated model,
    and its covariance (J^T J)^-1 from scipy's Jacobian at the minimum."""
    def residuals(theta):
        u, v = theta
        return (measured - table.profile(math.exp(u), math.exp(u + v))) / sigma

    best = least_squares(residuals, start, jac="3-point", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return best.x, 2.0 * best.cost, np.linalg.inv(best.jac.T @ best.jac)


@pytest.mark.parametrize("noise", [0.01, 0.06])
def test_fits_equal_scipys_least_squares(table, noise):
    measured, sigma = noisy_profiles(table, noise, seed=int(noise * 100))
    fitted = fit_profiles(table, measured, sigma, np.ones(3))
    assert (fitted["status"] == CONVERGED).all()
    for y, x, c in np.ndindex(fitted["u"].shape):
        mus, mua = TRUTHS[c]
        theta, chi2, covariance = scipy_fit(table, measured[:, y, x, c].astype(np.float64),
                                            sigma[:, y, x, c].astype(np.float64), [math.log(mus), math.log(mua / mus)])
        ours = np.array([fitted["u"][y, x, c], fitted["v"][y, x, c]])
        errors = np.sqrt(np.diag(covariance))
        # Within 3 % of a standard error of scipy's minimum (the fit stops within 1 % of its own).
        assert np.all(np.abs(ours - theta) < 0.03 * errors)
        assert fitted["chi2"][y, x, c] == pytest.approx(chi2, rel=1e-3, abs=1e-3)
        # Variances within 2 %, the correlation within 0.01 (scipy differentiates the model by finite
        # differences, the fit the splines).
        np.testing.assert_allclose([fitted["cuu"][y, x, c], fitted["cvv"][y, x, c]], np.diag(covariance), rtol=0.02)
        assert abs(fitted["cuv"][y, x, c] - covariance[0, 1]) < 0.01 * math.sqrt(covariance[0, 0] * covariance[1, 1])


def test_sigma_made_per_fit_equals_the_maps_array_of_it(table):
    # Standard errors with ring 0 undefined (one member) and a ring of a pixel missing: each fit's
    # own sigma must give the fits of the (R, H, W, C) array ring_sigma makes.
    measured, sigma = noisy_profiles(table, 0.03, seed=5)
    errors = sigma.copy()
    errors[0] = np.nan
    errors[3, 1, 4, 2] = np.nan
    counts = np.broadcast_to(np.array([1, 8, 12, 16, 32, 28, 40, 40])[:, None, None], measured.shape[:3])
    inflation = np.linspace(1.3, 1.1, 8)
    expected = fit_profiles(table, measured, ring_sigma(measured, errors * inflation[:, None, None, None], counts,
                                                        MODEL_FLOOR), np.ones(3))
    fitted = fit_profiles(table, measured, errors, np.ones(3), counts=counts, floor=MODEL_FLOOR, inflation=inflation)
    for name in ("u", "v"):
        spread = np.sqrt(expected["cuu" if name == "u" else "cvv"])
        assert np.all(np.abs(fitted[name] - expected[name]) < 0.03 * spread)
    np.testing.assert_allclose(fitted["cuu"], expected["cuu"], rtol=0.02)


def test_ring_sigma_borrows_the_nearest_rings_relative_error():
    # Ring 2 has no error: rings 1 and 3 are as near, the lower one's 10 % is taken, times
    # sqrt(8 / 12) for their members; ring 0 borrows ring 1's times sqrt(8 / 1). Floor 1 % added.
    images = np.array([8.0, 4.0, 2.0, 1.0]).reshape(4, 1, 1, 1)
    errors = np.array([np.nan, 0.4, np.nan, 0.3]).reshape(4, 1, 1, 1)
    counts = np.array([1, 8, 12, 16]).reshape(4, 1, 1)
    sigma = ring_sigma(images, errors, counts, 0.01).ravel()
    own = np.array([8.0 * 0.1 * math.sqrt(8.0), 0.4, 2.0 * 0.1 * math.sqrt(8 / 12), 0.3])
    np.testing.assert_allclose(sigma, np.hypot(own, 0.01 * images.ravel()), rtol=1e-6)
    # Only the last ring has one: every other ring borrows its 30 %, ring 0 from the farthest.
    errors = np.array([np.nan, np.nan, np.nan, 0.3]).reshape(4, 1, 1, 1)
    sigma = ring_sigma(images, errors, counts, 0.0).ravel()
    np.testing.assert_allclose(sigma, images.ravel() * 0.3 * np.sqrt(16 / counts.ravel()), rtol=1e-6)


def test_ring_sigma_docstring_example_runs():
    failures, _ = doctest.testmod(ring_sigma_module)
    assert failures == 0
