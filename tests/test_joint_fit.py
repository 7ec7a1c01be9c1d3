"""The joint fit of the channels (ringlight.core.inversion.joint) against a generalised chi-square
built here from its definition, a brute-force minimiser, noise drawn from its own noise model, and
sampled chromaticities; and how a layer's region joins its ellipse (layer_colour)."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.linalg import block_diag
from scipy.optimize import minimize
from scipy.spatial import ConvexHull
from scipy.stats import chi2 as chi2_distribution

from ringlight.core.colour.chroma import chromaticity
from ringlight.core.inversion.fit import RELATIVE_FLOOR, ChannelFit, fit_channels
from ringlight.core.inversion.forward import Forward, Structure, ring_matrix
from ringlight.core.inversion.joint import ELLIPSE_POINTS, JointFit, chromaticity_ellipse, fit_jointly
from ringlight.core.inversion.layer_colour import GRADIENT_STEP, chromaticity_gradient, layer_colours, region_contains
from ringlight.core.inversion.white_mc import SlabOptics, run_white
from ringlight.core.simulate.adding_doubling import thick_slab_reflectance

RADII = np.arange(0.0, 7.0)
REACH = 13
STARTS = (0, 2)
# A red top over a blue base (per channel, per layer), as in test_inversion's two-layer slab.
TRUTH = np.array([[0.3, 0.05, 0.01], [0.01, 0.02, 0.2]]).T  # (C, L)
# Every absorption large enough to be pinned to a few tens of per cent: the likelihood is nearly
# quadratic in log mua. (Under TRUTH, blue in the top layer (0.01) sometimes runs to the lower
# bound and the Fisher covariance understates: truth's Mahalanobis distance averaged 25 over 30
# draws, against 6; that is why a layer's region keeps the profile-likelihood box.)
DETERMINED = np.array([[0.3, 0.05, 0.03], [0.03, 0.05, 0.2]]).T


def white_forward(photons: int = 20_000):
    optics = SlabOptics((1.0,) * 5, 0.0, 1.3, 16.0, REACH)
    return Forward(run_white(optics, photons, seed=2), Structure(STARTS), RADII)


def brute_white_covariance(forward: Forward, mua: np.ndarray) -> np.ndarray:
    """(R, C, C) covariance between channels of the white run's profile, from a dense (photon,
    pixel) table of every record's weight, each layer's absorption applied bin by bin."""
    database = forward.database
    layer_of_bin = np.searchsorted(np.array(STARTS), np.arange(database.lengths.shape[1]), side="right") - 1
    rings = ring_matrix(RADII, REACH)
    per_photon = []
    for c in range(len(mua)):
        weight = database.value * np.exp(-(database.lengths @ mua[c, layer_of_bin]))
        table = np.zeros((database.photons, rings.shape[1]))
        np.add.at(table, (database.photon, database.pixel), weight)
        per_photon.append(table @ rings.T)  # (photons, R)
    per_photon = np.stack(per_photon)  # (C, photons, R)
    return np.stack([np.cov(per_photon[:, :, r], bias=True) for r in range(len(RADII))]) / database.photons


def log_covariance(forward, mua, measured, error, correlation):
    """(R, C, C) the joint fit's noise model in log space, built from its definition, with the floor
    ``correlation`` between channels."""
    floor = RELATIVE_FLOOR ** 2 * np.where(np.eye(3, dtype=bool), 1.0, correlation)
    covariance = []
    for r, white in enumerate(brute_white_covariance(forward, mua)):
        relative = 1.0 / measured[r]
        covariance.append(np.diag((error[r] * relative) ** 2) + white * np.outer(relative, relative) + floor)
    return np.array(covariance)


def generalised_chi2(forward, mua, measured, covariance, used):
    """r^T S^-1 r over every (ring, channel) a channel's own fit used, S block-diagonal by ring."""
    model = np.stack([forward.profile(mua[c]) for c in range(3)], axis=1)
    residual, blocks = [], []
    for r in range(int(used.max())):
        active = np.flatnonzero(r < used)
        residual.append(np.log(measured[r, active]) - np.log(model[r, active]))
        blocks.append(covariance[r][np.ix_(active, active)])
    residual = np.concatenate(residual)
    return float(residual @ np.linalg.solve(block_diag(*blocks), residual))


def test_joint_chi2_is_the_generalised_chi_square_and_no_minimiser_finds_lower():
    forward = white_forward()
    clean = np.stack([forward.profile(TRUTH[c]) for c in range(3)], axis=1)
    rng = np.random.default_rng(5)
    measured = clean * np.exp(0.02 * rng.standard_normal((len(RADII), 1)) + 0.005 * rng.standard_normal(clean.shape))
    error = 0.005 * measured
    fits = fit_channels(forward, measured, error, intervals=False)
    joint = fit_jointly(forward, measured, error, fits)
    used = np.array([f.used for f in fits])
    covariance = log_covariance(forward, joint.mua, measured, error, joint.floor_correlation)
    assert joint.points == used.sum() and joint.dof == used.sum() - 6
    np.testing.assert_allclose(joint.chi2, generalised_chi2(forward, joint.mua, measured, covariance, used), rtol=1e-6)
    np.testing.assert_allclose(joint.sigma, measured * np.sqrt(np.diagonal(covariance, axis1=1, axis2=2)),
                               rtol=1e-6)
    # Nelder-Mead on that chi-square (weights held at the result) from the channels' own fits
    # finds nothing lower.
    start = np.log(np.array([f.mua for f in fits])).ravel()
    search = minimize(lambda theta: generalised_chi2(forward, np.exp(theta.reshape(3, 2)), measured, covariance,
                                                     used), start, method="Nelder-Mead",
                      options={"xatol": 1e-6, "fatol": 1e-8, "maxiter": 20_000, "maxfev": 20_000})
    assert search.fun >= joint.chi2 - 1e-3, (search.fun, joint.chi2)
    np.testing.assert_allclose(np.exp(search.x.reshape(3, 2)), joint.mua, rtol=0.02)


def test_channels_fitting_different_rings_and_a_profile_falling_to_zero():
    """Blue is 0 beyond ring 3 (below any noise), red and green go on: each channel's residuals
    enter only at its own rings, nothing divides by the zeros (warnings are errors here), and every
    ring's sigma is its own noise, fitted or not."""
    forward = white_forward()
    measured = np.stack([forward.profile(TRUTH[c]) for c in range(3)], axis=1)
    measured *= np.exp(0.01 * np.random.default_rng(2).standard_normal(measured.shape))
    measured[4:, 2] = 0.0
    error = 0.005 * measured
    error[5:, :2] = 0.5 * measured[5:, :2]  # red and green stop at ring 5 (below 3 sigma there)
    fits = fit_channels(forward, measured, error, intervals=False)
    used = np.array([f.used for f in fits])
    assert used.tolist() == [5, 5, 4]
    joint = fit_jointly(forward, measured, error, fits)
    assert joint.points == 14
    scale = np.where(measured > 0, measured, 1.0)  # where it is 0 the log covariance is not used
    covariance = log_covariance(forward, joint.mua, scale, error, joint.floor_correlation)
    np.testing.assert_allclose(joint.chi2, generalised_chi2(forward, joint.mua, measured, covariance, used), rtol=1e-6)
    white = np.diagonal(brute_white_covariance(forward, joint.mua), axis1=1, axis2=2)
    expected = np.sqrt(error ** 2 + white + (RELATIVE_FLOOR * measured) ** 2)
    np.testing.assert_allclose(joint.sigma, expected, rtol=1e-6)
    assert np.all(joint.sigma[4:, 2] > 0) and np.all(joint.sigma[5:, :2] > 0.4 * measured[5:, :2])


def test_joint_fit_is_calibrated_under_its_own_noise_model():
    """Profiles drawn with exactly the noise the joint fit assumes (the white run's own covariance
    included): its chi-square averages its degrees of freedom, and the truth's Mahalanobis distance
    under its covariance averages the parameter count (chi-square distributions). Measured with a
    white run of 20 000 photons: 14.3 for 15 degrees of freedom, 6.08 for 6 parameters (the floor's
    correlation, drawn 0.9, chosen 0.9 in 25 draws of 30; 15.2 and 6.36 with it held at 0.9); with
    the 5000 photons used here (the white run's covariance is part of the model the noise is drawn
    from, so the check holds at any count, and the 30 fits take a quarter of the time): 14.3 and 6.50."""
    forward = white_forward(5000)
    clean = np.stack([forward.profile(DETERMINED[c]) for c in range(3)], axis=1)
    error = 0.01 * clean
    factors = np.linalg.cholesky(log_covariance(forward, DETERMINED, clean, error, 0.9))  # (R, C, C)
    rng = np.random.default_rng(0)
    chi2, distance = [], []
    for _ in range(30):
        noise = np.einsum("rij,rj->ri", factors, rng.standard_normal(clean.shape))
        measured = clean * np.exp(noise)
        joint = fit_jointly(forward, measured, error, fit_channels(forward, measured, error, intervals=False))
        deviation = np.log(joint.mua).ravel() - np.log(DETERMINED).ravel()
        chi2.append(joint.chi2)
        distance.append(deviation @ np.linalg.solve(joint.covariance, deviation))
    dof = joint.dof
    # Means of 30 draws: chi-square(15) has standard error 1.0, chi-square(6) 0.63.
    assert abs(np.mean(chi2) - dof) < 3.5, (np.mean(chi2), dof)
    assert abs(np.mean(distance) - 6) < 2.5, np.mean(distance)


def test_the_floor_correlation_is_chosen_by_likelihood():
    """A floor of 1 % drawn independent between channels, then correlated 0.9 (15 profiles each):
    the fit picks a correlation near the one drawn, and its chi-square is what the noise gives. A
    fit held at 0.9 averaged chi2/dof 2.0 on the independent profiles, up to 4.3, past the misfit
    threshold of 2.5 at 15 dof. Measured: independent, 0 or 0.5 chosen 13 times of 15, chi2/dof
    0.77 on average, 1.31 at most; correlated, 0.9 every time, 0.44 and 0.98."""
    forward = white_forward()
    clean = np.stack([forward.profile(DETERMINED[c]) for c in range(3)], axis=1)
    for drawn in (0.0, 0.9):
        floor = np.linalg.cholesky(RELATIVE_FLOOR ** 2 * np.where(np.eye(3, dtype=bool), 1.0, drawn))
        rng = np.random.default_rng(0)
        chosen, per_dof = [], []
        for _ in range(15):
            measured = clean * np.exp(rng.standard_normal(clean.shape) @ floor.T
                                      + 0.003 * rng.standard_normal(clean.shape))
            error = 0.003 * measured
            joint = fit_jointly(forward, measured, error, fit_channels(forward, measured, error, intervals=False))
            chosen.append(joint.floor_correlation)
            per_dof.append(joint.chi2 / joint.dof)
        near = np.abs(np.array(chosen) - drawn) <= 0.5
        assert np.mean(near) >= 0.8, (drawn, chosen)
        assert np.mean(per_dof) < 1.2 and max(per_dof) < chi2_distribution.isf(1e-3, joint.dof) / joint.dof, per_dof


def test_chromaticity_ellipse_holds_its_share_of_sampled_colours():
    """The delta-method ellipse of a colour against the chromaticities of absorptions drawn from
    the covariance: 95.4 % inside, for a spread small enough to be linear. The colour is a closed
    form thick-slab reflectance (Kubelka-Munk's, R = 1 + a - sqrt(a^2 + 2a) with a = mua / mus),
    as curved in mua as the adding-doubling one and a thousand times cheaper to sample."""
    mua = np.array([0.2, 0.03, 0.01])
    spread = np.array([0.03, 0.05, 0.08])
    correlation = np.array([[1.0, 0.6, 0.3], [0.6, 1.0, 0.5], [0.3, 0.5, 1.0]])
    covariance = correlation * np.outer(spread, spread)

    def xy(log_mua):
        ratio = np.exp(log_mua)
        return chromaticity(1.0 + ratio - np.sqrt(ratio ** 2 + 2.0 * ratio), "sRGB")

    step = 1e-5
    gradient = np.stack([(xy(np.log(mua) + step * e) - xy(np.log(mua) - step * e)) / (2 * step)
                         for e in np.eye(3)], axis=1)
    ellipse = chromaticity_ellipse(xy(np.log(mua)), gradient, covariance)
    assert ellipse.shape == (ELLIPSE_POINTS, 2)
    samples = xy(np.random.default_rng(1).multivariate_normal(np.log(mua), covariance, 4000))
    share = np.mean([region_contains(ellipse, point) for point in samples])
    # Binomial standard error at 4000 draws: 0.0033; the inscribed 32-gon loses about 0.3 %.
    # Measured: 0.953.
    assert abs(share - chi2_distribution.cdf(chi2_distribution.ppf(0.954, 2), 2)) < 0.015, share


def test_no_joint_fit_without_every_channels_own_fit():
    forward = white_forward(4_000)
    measured = np.stack([forward.profile(TRUTH[c]) for c in range(3)], axis=1)
    measured[1:, 2] = 0.0  # blue stands out of the noise at r = 0 only: its own fit fails
    error = 0.01 * measured + 1e-9
    fits = fit_channels(forward, measured, error, intervals=False)
    assert np.isnan(fits[2].mua).all() and fit_jointly(forward, measured, error, fits) is None


def test_layer_region_joins_the_ellipse_only_where_the_chi_square_is_quadratic():
    """A one-layer fit with a tight per-channel box: the joint fit's ellipse (Fisher standard
    deviations 0.3 in log absorption) widens the region to hold it; with one channel's at 2 (a
    weakly absorbing channel, where the Wald ellipse fails) the region is the box's image alone."""
    optics = SlabOptics((1.0,) * 3, 0.0, 1.3, 8.0, REACH)
    mua = np.array([0.2, 0.03, 0.01])
    fits = [ChannelFit(np.array([m]), np.array([[0.98 * m, 1.02 * m]]), np.zeros(1, bool), 7, 5.0, np.ones(7),
                       np.ones(7)) for m in mua]
    colour = thick_slab_reflectance(np.ones(3), mua, 0.0, 1.3)
    centre = chromaticity(colour, "sRGB")

    def region(spread):
        joint = JointFit(mua[:, None], np.diag(np.square(spread)), 5.0, 5.0, 0.9, 21, np.ones((7, 3)),
                         np.ones((7, 3)))
        (layer,) = layer_colours(fits, Structure((0,)), optics, "sRGB", joint)
        np.testing.assert_allclose(layer.xy, centre, atol=1e-12)
        return layer.region

    step = 1e-5
    gradient = np.stack([(chromaticity(thick_slab_reflectance(np.ones(3), mua * np.exp(step * e), 0.0, 1.3), "sRGB")
                          - chromaticity(thick_slab_reflectance(np.ones(3), mua * np.exp(-step * e), 0.0, 1.3),
                                         "sRGB")) / (2 * step) for e in np.eye(3)], axis=1)
    ellipse = chromaticity_ellipse(centre, gradient, np.diag(np.full(3, 0.3 ** 2)))
    ellipse = centre + 0.99 * (ellipse - centre)  # the region's float32 edges pass through its points
    quadratic = region([0.3, 0.3, 0.3])
    assert all(region_contains(quadratic, point) for point in ellipse)
    box = region([0.3, 0.3, 2.0])
    assert not any(region_contains(box, point) for point in ellipse)
    assert np.ptp(box, axis=0).max() < 0.2 * np.ptp(quadratic, axis=0).max()


def test_a_layers_box_and_colour_gradient_equal_every_corner_and_step_solved_whole():
    """Each channel's colour is solved at its own absorptions only (a thick slab's channel depends
    on its own absorption): the box's image equals the hull of the colours of all 8 corners solved
    as whole RGB triples, and the gradient equals central differences of xy solved whole at each
    step, to 1e-12 (in float32 for the hull's vertices)."""
    optics = SlabOptics((1.0,) * 3, 0.0, 1.3, 8.0, REACH)
    mua = np.array([0.2, 0.03, 0.01])
    interval = np.stack([0.7 * mua, 1.6 * mua], axis=1)
    fits = [ChannelFit(np.array([m]), interval[c][None], np.zeros(1, bool), 7, 5.0, np.ones(7), np.ones(7))
            for c, m in enumerate(mua)]
    (layer,) = layer_colours(fits, Structure((0,)), optics, "sRGB")
    corners = np.array(list(itertools.product(*interval)))  # (8, 3) absorptions
    xy = np.array([chromaticity(thick_slab_reflectance(np.ones(3), corner, 0.0, 1.3), "sRGB") for corner in corners])
    hull = xy[ConvexHull(xy).vertices].astype(np.float32)
    assert len(layer.region) == len(hull)
    for vertex in hull:
        assert np.abs(layer.region - vertex).max(axis=1).min() <= 1e-7
    whole = lambda theta: chromaticity(thick_slab_reflectance(np.ones(3), np.exp(theta), 0.0, 1.3), "sRGB")
    theta = np.log(mua)
    brute = np.stack([(whole(theta + GRADIENT_STEP * e) - whole(theta - GRADIENT_STEP * e)) / (2 * GRADIENT_STEP)
                      for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(chromaticity_gradient(1.0, mua, optics, "sRGB"), brute, rtol=1e-12, atol=1e-12)
