"""Ring-spread standard errors of E_r and T_r against brute force, their statistics on simulated
slabs, and the SNR summaries and display denoise built on them."""

import math

import numpy as np
import pytest
from reference import random_impulses, write_dataset
from ringlight.core import Cancelled, annulus_pixel_area, open_dataset, transient_stack
from ringlight.core.colour.chroma import luminance
from ringlight.core.rings.noise import (
    luminance_weights,
    median_snr,
    region_snr,
    smoothed,
    stack_noise,
    transient_snr,
)
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import simulate_transport, write_transport

REC709_Y = np.array([0.2126, 0.7152, 0.0722])  # ITU-R BT.709 luminance row, sRGB's


def brute_ring_se(impulses, height, width, radius, thickness=1.0, weight=None):
    """SE of E_r by the definition: gather each pixel's lit ring members, group them by distance,
    pool numpy's weighted covariances of the groups (aweights, ddof 1: sum w d^2 / (V1 - V2/V1))
    by their degrees of freedom and multiply by V2 / V1^2 of the whole ring (Kish).

    Returns (H, W, 3) per channel and (H, W) of Rec. 709 luminance; NaN without a group of 2."""
    se = np.full((height, width, 3), np.nan)
    se_y = np.full((height, width), np.nan)
    for y in range(height):
        for x in range(width):
            groups = {}
            for (qy, qx), image in impulses.items():
                dy, dx = qy - y, qx - x
                if weight is None:
                    w = 1.0 if radius - thickness / 2 <= math.hypot(dy, dx) < radius + thickness / 2 else 0.0
                else:
                    w = weight(dy, dx)
                if w > 0:
                    values = np.append(image[y, x].astype(np.float64), image[y, x] @ REC709_Y)
                    groups.setdefault(dy * dy + dx * dx, []).append((w, values))
            squares, dof, all_weights = np.zeros(4), 0.0, []
            for members in groups.values():
                weights = np.array([w for w, _ in members])
                all_weights.extend(weights)
                if len(members) < 2:
                    continue
                values = np.array([v for _, v in members])
                group_dof = weights.sum() - (weights ** 2).sum() / weights.sum()
                squares += [np.cov(values[:, c], aweights=weights) * group_dof for c in range(4)]
                dof += group_dof
            if dof == 0:
                continue
            all_weights = np.array(all_weights)
            kish = (all_weights ** 2).sum() / all_weights.sum() ** 2
            errors = np.sqrt(squares / dof * kish)
            se[y, x], se_y[y, x] = errors[:3], errors[3]
    return se, se_y


@pytest.fixture(scope="module")
def random_dataset(tmp_path_factory):
    rng = np.random.default_rng(11)
    height, width = 9, 8
    impulses = random_impulses(rng, height, width, support=5.0, missing=0.1)
    folder = tmp_path_factory.mktemp("noise") / "random"
    write_dataset(folder, height, width, impulses, max_radius=5.0)
    return impulses, open_dataset(folder, use_cache=False)


def test_luminance_weights_are_the_layer_recovery_luminance():
    assert np.allclose(luminance_weights("sRGB"), REC709_Y, atol=1e-4)
    rgb = np.random.default_rng(0).random((4, 3))
    assert np.allclose(rgb @ luminance_weights("ACEScg"), luminance(rgb, "ACEScg"))


def test_ring_and_transient_se_equal_brute_force_member_spread(random_dataset):
    impulses, dataset = random_dataset
    radii = [0.0, 1.0, 2.5, 3.0]
    noise = stack_noise(dataset, radii, step=1.0)
    for index, radius in enumerate(radii):
        inner, inner_y = brute_ring_se(impulses, 9, 8, radius)
        outer, outer_y = brute_ring_se(impulses, 9, 8, radius + 1.0)
        np.testing.assert_allclose(noise.ring[index], inner, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(noise.ring_luminance[index], inner_y, rtol=1e-5, atol=1e-7)
        # Disjoint rings: variances add.
        np.testing.assert_allclose(noise.transient[index], np.sqrt(inner ** 2 + outer ** 2), rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(noise.transient_luminance[index], np.hypot(inner_y, outer_y), rtol=1e-5, atol=1e-7)
    # r = 0 has one member: undefined, as is every ring with fewer than two lit members.
    assert np.isnan(noise.ring[0]).all()
    assert np.isnan(noise.transient[0]).all()
    assert np.isfinite(noise.ring[2]).sum() > 0.9 * noise.ring[2].size


def test_antialiased_se_uses_the_effective_sample_size(random_dataset):
    impulses, dataset = random_dataset
    radius = 2.2
    noise = stack_noise(dataset, [radius], step=1.0, antialias=True)

    def area(r):  # the geometry keeps pixels covering more than 1e-12
        def weight(dy, dx):
            value = float(annulus_pixel_area(dy, dx, max(r - 0.5, 0.0), r + 0.5))
            return value if value > 1e-12 else 0.0
        return weight

    inner, inner_y = brute_ring_se(impulses, 9, 8, radius, weight=area(radius))
    outer, _ = brute_ring_se(impulses, 9, 8, radius + 1.0, weight=area(radius + 1.0))
    np.testing.assert_allclose(noise.ring[0], inner, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(noise.ring_luminance[0], inner_y, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(noise.transient[0], np.hypot(inner, outer), rtol=1e-5, atol=1e-7)


def test_snr_summaries_equal_direct_computation(random_dataset):
    _, dataset = random_dataset
    radii = [1.0, 2.0, 3.0]
    stack = transient_stack(dataset, radii, step=1.0)
    noise = stack_noise(dataset, radii, step=1.0)
    snr = transient_snr(stack.images, noise)
    y = np.abs(stack.images.astype(np.float64) @ REC709_Y)
    np.testing.assert_allclose(snr, y / noise.transient_luminance, rtol=2e-4)
    region = np.zeros(dataset.grid_shape, bool)
    region[2:7, 1:5] = True
    for index in range(3):
        values = snr[index][region]
        assert median_snr(snr, region)[index] == pytest.approx(np.median(values[np.isfinite(values)]))
        # Region mean over the defined pixels; SE of a mean of m independent pixels.
        luminance_values = stack.images[index][region].astype(np.float64) @ REC709_Y
        errors = noise.transient_luminance[index][region].astype(np.float64)
        defined = np.isfinite(luminance_values)
        expected = luminance_values[defined].mean() / math.sqrt(
            np.nanmean(errors[defined] ** 2) / defined.sum())
        assert region_snr(stack.images, noise, region)[index] == pytest.approx(expected, rel=1e-4)
    assert np.isnan(median_snr(np.full((1, 2, 2), np.nan))).all()


def homogeneous_slab(seed):
    return parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": 15, "width": 15},
        "depth": 30, "n": 1.0, "materials": {"m": {"mus": [1.5] * 3, "mua": [0.1] * 3}},
        "background": "m", "photons_per_point": 1500, "max_radius": 5.0,
        "path_length_bins": {"step": 1.0, "count": 4}, "seed": seed,
    })


def test_se_of_t_predicts_the_spread_between_two_simulated_seeds(tmp_path):
    """On a homogeneous slab ring members differ by photon noise only, so SE(T_r) from one run
    must predict |T_a - T_b| between two independent runs: E[(T_a - T_b)^2] = SE_a^2 + SE_b^2.

    The analogue estimator gives every lit point its own photons, as a capture measures each lit
    point apart; the reference estimator shares one kernel between them, whose noise no spread
    between ring members can show (there SE is 0 in a homogeneous slab)."""
    stacks, noises = [], []
    radii = [1.0, 2.0, 3.0]
    for seed in (1, 2):
        transport = simulate_transport(homogeneous_slab(seed), estimator="analogue")
        folder = write_transport(transport, tmp_path / f"slab{seed}")
        dataset = open_dataset(folder, use_cache=False)
        stacks.append(transient_stack(dataset, radii, step=1.0))
        noises.append(stack_noise(dataset, radii, step=1.0))
    inner = (slice(None), slice(4, 11), slice(4, 11))  # away from the slab's sides
    difference = (stacks[0].images - stacks[1].images)[inner]
    predicted = (noises[0].transient ** 2 + noises[1].transient ** 2)[inner]
    for index in range(len(radii)):
        ratio = np.mean(difference[index] ** 2) / np.mean(predicted[index])
        # 49 pixels x 3 channels of a chi-square-like ratio: well within a factor of 2 of 1.
        assert 0.5 < ratio < 2.0, (radii[index], ratio)


def test_smoothing_is_a_normalised_gaussian_that_keeps_nan():
    rng = np.random.default_rng(2)
    image = rng.random((12, 10, 3)).astype(np.float32)
    image[3, 4] = np.nan
    sigma = 1.5
    result = smoothed(image, sigma)
    # Direct normalised convolution with OpenCV's kernel (size 2 * round(4 sigma) + 1 for float).
    radius = int(round(4 * sigma))
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-offsets ** 2 / (2 * sigma ** 2))
    y, x = 6, 5
    total, weight = np.zeros(3), 0.0
    for dy, ky in zip(offsets, kernel):
        for dx, kx in zip(offsets, kernel):
            if 0 <= y + dy < 12 and 0 <= x + dx < 10 and np.isfinite(image[y + dy, x + dx]).all():
                total += ky * kx * image[y + dy, x + dx]
                weight += ky * kx
    np.testing.assert_allclose(result[y, x], total / weight, rtol=1e-4)
    assert np.isnan(result[3, 4]).all() and np.isfinite(np.delete(result.reshape(-1, 3), 3 * 10 + 4, 0)).all()
    assert smoothed(image[..., 0], sigma).shape == (12, 10)


def test_a_noiseless_homogeneous_surface_has_zero_standard_error(tmp_path):
    # I_q(p) = exp(-|p - q| / 2): members differ only by their distance, which the pooling
    # within distance groups keeps out of the spread (a plain ring variance would not be 0).
    size = 11
    yy, xx = np.mgrid[:size, :size]
    impulses = {(y, x): np.repeat(np.exp(-np.hypot(yy - y, xx - x) / 2)[..., None], 3, -1).astype(np.float32)
                for y in range(size) for x in range(size)}
    write_dataset(tmp_path / "d", size, size, impulses, max_radius=4.0)
    noise = stack_noise(open_dataset(tmp_path / "d", use_cache=False), [1.0, 2.0], step=1.0)
    np.testing.assert_allclose(noise.transient[:, 3:8, 3:8], 0.0, atol=1e-7)
    assert np.isfinite(noise.transient).all()


def test_progress_reaches_one_and_a_cancel_stops_the_estimate(random_dataset):
    _, dataset = random_dataset
    fractions = []
    stack_noise(dataset, [1.0, 2.0], progress=fractions.append)
    assert fractions == sorted(fractions) and fractions[-1] == 1.0

    def cancel(fraction):
        raise Cancelled("cancelled")
    with pytest.raises(Cancelled):
        stack_noise(dataset, [1.0, 2.0], progress=cancel)


def test_the_spread_is_the_same_band_by_band_and_its_kernel_compiled_for_whole_outputs(random_dataset,
                                                                                         monkeypatch):
    """Bands of 2 rows (as a large dataset's) give the one band's standard errors, and the kernel
    writes into the whole (n, H, W) outputs: each band's slice was strided where one band's is
    contiguous, two compiles of the same kernel (9-17 s each)."""
    from ringlight.core.dataset.impulse_dataset import ImpulseDataset
    from ringlight.core.rings.noise import _spread_kernel

    _, dataset = random_dataset
    whole = stack_noise(dataset, [0.0, 1.0, 2.0])
    monkeypatch.setattr(ImpulseDataset, "band_height", property(lambda self: 2))
    assert len(dataset.bands()) == 5
    banded = stack_noise(dataset, [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(banded.ring, whole.ring)
    np.testing.assert_array_equal(banded.ring_luminance, whole.ring_luminance)
    assert all(signature[-1].layout == signature[-2].layout == "C" for signature in _spread_kernel.signatures)
