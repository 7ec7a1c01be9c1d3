"""The maps' estimator (Gauss-Newton steps from a fine table's nodes) against the full
Levenberg-Marquardt fit on the table's splines, its reference, and the fine nodes (the model, its
Jacobian and Hessian) against the splines themselves."""

import math

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS
from ringlight.core.optics import radial
from ringlight.core.optics.maps import MODEL_FLOOR
from ringlight.core.optics.node_fit import fine_nodes
from ringlight.core.optics.pixel_fit import CONVERGED, NO_DATA, fit_profiles
from ringlight.core.optics.table import build_table, interpolate

TRUTHS = [(0.5, 0.02), (0.15, 0.005), (1.2, 0.1)]  # (mus, mua) per grid step, one per channel


@pytest.fixture(scope="module")
def table():
    return build_table(radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0), np.arange(8.0))


def spline(table, u, v):
    """(R,) E of the table's spline look-up at u = log mus, v = log (mua / mus)."""
    return table.profile(math.exp(u), math.exp(u + v))


def spline_jacobian(table, u, v):
    """(2, R) dE/du and dE/dv of the table's spline at (u, v), from its own look-up's derivatives."""
    values, slopes = np.empty(len(table.radii)), np.empty((2, len(table.radii)))
    assert interpolate(table.log_profile, table.u0, table.du, table.v0, table.dv, u, v, values, slopes)
    return np.exp(values) * slopes


def test_fine_nodes_equal_the_tables_spline(table):
    nodes, u0, du, v0, dv = fine_nodes(table)
    rng = np.random.default_rng(3)
    picks = list(zip(rng.integers(0, nodes.shape[0], 300), rng.integers(0, nodes.shape[1], 300)))
    picks.append((nodes.shape[0] - 1, nodes.shape[1] - 1))  # the spline range's last node
    checked = 0
    for k, j in picks:
        # The spline and its derivatives (central differences of its look-up).
        u, v = min(u0 + k * du, u0 + (nodes.shape[0] - 1.0) * du - 1e-12), v0 + j * dv
        model = spline(table, u, v)
        if not np.all(model > 1e-25):
            assert not np.isfinite(nodes[k, j, 0, model <= 1e-30]).any()  # too small for float32: sent to the full fit
            continue
        np.testing.assert_allclose(nodes[k, j, 0], model, rtol=1e-6)
        if 0 < k < nodes.shape[0] - 1 and 0 < j < nodes.shape[1] - 1:
            h, tolerance = 1e-5, 1e-6 * np.abs(model).max()
            slope_u = (spline(table, u + h, v) - spline(table, u - h, v)) / (2 * h)
            slope_v = (spline(table, u, v + h) - spline(table, u, v - h)) / (2 * h)
            np.testing.assert_allclose(nodes[k, j, 1], slope_u, rtol=1e-4, atol=tolerance)
            np.testing.assert_allclose(nodes[k, j, 2], slope_v, rtol=1e-4, atol=tolerance)
            # The Hessian: central differences of the spline's Jacobian at the neighbouring fine nodes.
            up, down = spline_jacobian(table, u + du, v), spline_jacobian(table, u - du, v)
            right, left = spline_jacobian(table, u, v + dv), spline_jacobian(table, u, v - dv)
            tolerance = 1e-5 * np.abs(up).max() / du
            np.testing.assert_allclose(nodes[k, j, 3], (up[0] - down[0]) / (2 * du), rtol=1e-5, atol=tolerance)
            np.testing.assert_allclose(nodes[k, j, 4], ((right[0] - left[0]) / dv + (up[1] - down[1]) / du) / 4,
                                       rtol=1e-5, atol=tolerance)
            np.testing.assert_allclose(nodes[k, j, 5], (right[1] - left[1]) / (2 * dv), rtol=1e-5, atol=tolerance)
        checked += 1
    assert checked > 200


def noisy_map(table, noise, seed, width=60, height=3):
    """(R, H, W, 3) profiles of TRUTHS (a channel each), relative Gaussian ``noise``; standard errors
    as the stack gives them (ring 0 without one), and the rings' member counts."""
    rng = np.random.default_rng(seed)
    truth = np.stack([table.profile(mus, mua) for mus, mua in TRUTHS], axis=-1)  # (R, 3)
    shape = (len(table.radii), height, width, 3)
    counts = np.broadcast_to(np.array([1, 8, 12, 16, 32, 28, 40, 40])[:, None, None], shape[:3])
    errors = noise * truth[:, None, None, :] / np.sqrt(counts[..., None])
    measured = truth[:, None, None, :] + errors * rng.standard_normal(shape)
    errors = errors * np.sqrt(rng.chisquare(6, shape) / 6)  # estimated, as the ring spread's are
    errors[0] = np.nan
    return measured.astype(np.float32), errors.astype(np.float32), counts


def assert_fits_agree(full, nodes, bound):
    """Same statuses; where converged, (u, v) within ``bound`` of the full fit's standard errors,
    standard errors within 1 %, chi2 within 0.1 (its spread over pixels, 6 degrees of freedom, is 3.5)."""
    np.testing.assert_array_equal(nodes["status"], full["status"])
    np.testing.assert_array_equal(nodes["rings"], full["rings"])
    done = full["status"] == CONVERGED
    for name, variance in (("u", "cuu"), ("v", "cvv")):
        difference = np.abs(nodes[name] - full[name])[done] / np.sqrt(full[variance][done])
        assert difference.max() < bound
        np.testing.assert_allclose(np.sqrt(nodes[variance][done]), np.sqrt(full[variance][done]), rtol=0.01)
    correlation = (nodes["cuv"] - full["cuv"])[done] / np.sqrt(full["cuu"] * full["cvv"])[done]
    assert np.abs(correlation).max() < 0.01
    np.testing.assert_allclose(nodes["chi2"][done], full["chi2"][done], atol=0.1)


@pytest.mark.parametrize("noise", [0.01, 0.05])
def test_node_fits_agree_with_the_full_fit_within_a_twentieth_of_a_standard_error(table, noise):
    measured, errors, counts = noisy_map(table, noise, seed=int(noise * 100))
    measured[:, 1, 20, 0] = np.nan  # a pixel without data: the next starts from the chunk's start
    scale = np.array([1.0, 2.5, 0.4])  # a rig's scale per channel (calibration)
    measured, errors = measured * scale.astype(np.float32), errors * scale.astype(np.float32)
    fits = {estimator: fit_profiles(table, measured, errors, scale, counts=counts, floor=MODEL_FLOOR,
                                    inflation=np.full(8, 1.2), estimator=estimator) for estimator in ("full", "nodes")}
    assert fits["full"]["status"][1, 20, 0] == NO_DATA
    assert (fits["full"]["status"] == CONVERGED).sum() == measured[0].size - 1
    # Both stop within about 1 % of a standard error of the minimum (their own tolerances).
    assert_fits_agree(fits["full"], fits["nodes"], 0.05)
    # Node steps made them: the full fit only for each row's and channel's first (and no fit where
    # there are no data).
    assert (fits["nodes"]["node_steps"] == 0).sum() == 3 * 3 + 1
    assert (fits["full"]["node_steps"] == 0).all()


def test_node_fits_of_alternating_materials_agree_with_the_full_fit(table):
    # Neighbours far apart in (u, v): each fit's start is a poor one, so node steps do not settle
    # within NODE_STEPS and the fit is the full one, or settle after several.
    measured, errors, counts = noisy_map(table, 0.03, seed=7)
    measured[:, :, 1::2] = measured[:, :, 1::2, ::-1]
    errors[:, :, 1::2] = errors[:, :, 1::2, ::-1]
    fits = {estimator: fit_profiles(table, measured, errors, np.ones(3), counts=counts, floor=MODEL_FLOOR,
                                    estimator=estimator) for estimator in ("full", "nodes")}
    assert (fits["full"]["status"] == CONVERGED).all()
    assert_fits_agree(fits["full"], fits["nodes"], 0.05)
    steps = np.bincount(fits["nodes"]["node_steps"].ravel(), minlength=5)
    assert steps[0] > 3 * 3 and steps[2:].sum() > 0  # full fits beyond the rows' first, and several steps


def test_unknown_estimator_is_refused(table):
    measured, errors, counts = noisy_map(table, 0.03, seed=1, width=2, height=1)
    with pytest.raises(ValueError, match="estimator"):
        fit_profiles(table, measured, errors, np.ones(3), estimator="sfdi")
