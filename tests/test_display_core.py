"""Display pipeline, profiles, ground-truth matching, stack requests and image exports (core)."""

import math

import cv2
import numpy as np
import pytest
from reference import brute_ring_image, random_impulses, write_dataset
from ringlight.core import (
    Cancelled,
    StackError,
    open_dataset,
    ring_stack,
    transient_stack,
)
from ringlight.core.colour.display import (
    UNDEFINED_RGB,
    DisplaySettings,
    display_levels,
    diverging_lut,
    negative_fraction,
    render,
    scalar_lut,
)
from ringlight.core.colour.image_export import (
    ExportError,
    movie_scale,
    write_movie,
    write_png,
)
from ringlight.core.colourspaces import colour_module
from ringlight.core.dataset.ground_truth import (
    PathLengthImages,
    normalised_cross_correlation,
    scaled_difference,
)
from ringlight.core.rings.profiles import pixel_profile, profile_rings
from ringlight.core.rings.radii import needed_radius
from ringlight.core.rings.stack_request import (
    StackRequest,
    compute_stacks,
    default_request,
    largest_stop,
)


@pytest.fixture(scope="module")
def impulses():
    return random_impulses(np.random.default_rng(3), 9, 10, support=4.0, missing=0.1)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, impulses):
    folder = tmp_path_factory.mktemp("display") / "ds"
    write_dataset(folder, 9, 10, impulses, max_radius=4.0)
    return open_dataset(folder, use_cache=False)


def test_render_matches_colour_science_srgb_encoding_after_a_primaries_change():
    rng = np.random.default_rng(0)
    image = rng.uniform(0, 2, (5, 6, 3)).astype(np.float32)
    image[0, 0, 1] = np.nan
    settings = DisplaySettings(exposure_stops=-1.0)
    colour = colour_module()
    pixels = render(image, (0.0, 0.8), settings, "ACEScg")
    linear_srgb = colour.RGB_to_RGB(np.nan_to_num(image) * 0.5, "ACEScg", "sRGB",
                                    chromatic_adaptation_transform="Bradford")
    expected = np.round(colour.cctf_encoding(np.clip(linear_srgb / 0.8, 0, 1), function="sRGB") * 255)
    assert tuple(pixels[0, 0]) == UNDEFINED_RGB
    assert np.abs(pixels.astype(int) - expected.astype(int))[1:].max() <= 1


def test_levels_are_robust_maxima_of_finite_values_and_never_zero():
    values = np.concatenate([np.linspace(0, 1, 1001), [np.nan, np.inf, 1e6]]).astype(np.float32)
    low, high = display_levels(values, DisplaySettings(percentile=50))
    assert low == 0 and high == pytest.approx(np.percentile(values[np.isfinite(values)], 50))
    grey = np.repeat(-values[:, None], 3, axis=1)  # a signed view's levels are its luminance's
    assert display_levels(grey, DisplaySettings(percentile=50, diverging=True))[1] == pytest.approx(high)
    assert display_levels(np.zeros(4), DisplaySettings()) == (0.0, 1.0)
    assert display_levels(values, DisplaySettings(normalisation="log", percentile=50, log_decades=2))[0] == pytest.approx(high / 100)
    assert display_levels(values, DisplaySettings(normalisation="manual", manual_levels=(-1, 3))) == (-1.0, 3.0)
    with pytest.raises(ValueError, match="normalisation"):
        DisplaySettings(normalisation="auto")


def test_diverging_map_is_white_at_zero_and_symmetric_in_sign():
    image = np.zeros((1, 3, 3), np.float32)
    image[0, 0] = -1.0
    image[0, 2] = 1.0
    pixels = render(image, (-1.0, 1.0), DisplaySettings(diverging=True)).astype(int)
    assert (pixels[0, 1] == 247).all()  # RdBu centre
    assert pixels[0, 0, 2] > pixels[0, 0, 0] and pixels[0, 2, 0] > pixels[0, 2, 2]
    assert negative_fraction(image) == pytest.approx(3 / 9)  # one pixel of three, all channels


def test_one_channel_views_show_that_channel_or_luminance_through_the_map():
    rng = np.random.default_rng(1)
    image = rng.uniform(0, 2, (4, 5, 3)).astype(np.float32)
    image[0, 0, 2] = np.nan
    colour = colour_module()
    for channel, values in (("R", image[..., 0]), ("B", image[..., 2]),
                            ("Y", colour.RGB_to_XYZ(image, "ACEScg")[..., 1])):
        settings = DisplaySettings(channel=channel)
        low, high = display_levels(image, settings, "ACEScg")
        finite = values[np.isfinite(values)]
        assert (low, high) == (0.0, pytest.approx(np.percentile(finite, 99.5), rel=1e-5))
        pixels = render(image, (0.0, 1.5), settings, "ACEScg").astype(int)
        expected = np.round(colour.cctf_encoding(np.clip(np.nan_to_num(values) / 1.5, 0, 1), function="sRGB") * 255)
        assert tuple(pixels[0, 0]) == UNDEFINED_RGB
        grey = pixels.reshape(-1, 3)[1:]
        assert (grey[:, 0] == grey[:, 1]).all() and (grey[:, 1] == grey[:, 2]).all()
        assert np.abs(pixels[..., 0] - expected)[1:].max() <= 1
    lut = np.stack([np.arange(256), 255 - np.arange(256), np.full(256, 7)], -1).astype(np.uint8)
    pixels = render(image, (0.5, 1.5), DisplaySettings(channel="G"), "sRGB", lut)
    position = np.clip((image[..., 1] - 0.5) / 1.0, 0, 1)
    np.testing.assert_array_equal(pixels[1:, :, 0], np.round(position * 255)[1:])
    assert (pixels[1:, :, 2] == 7).all()
    decades = render(np.array([[[1e-3, 0, 0], [1e-1, 0, 0], [1.0, 0, 0]]], np.float32), (1e-3, 1.0),
                     DisplaySettings(channel="R", normalisation="log", log_decades=3))
    assert decades[0, :, 0].tolist() == [0, 170, 255]  # log10 positions 0, 2/3, 1 on a plain ramp


def test_a_diverging_map_given_as_a_table_puts_zero_at_its_middle():
    image = np.array([[[-2.0] * 3, [0.0] * 3, [2.0] * 3]], np.float32)
    lut = np.stack([np.arange(255), np.arange(255), np.arange(255)], -1).astype(np.uint8)  # 255 entries
    pixels = render(image, (-2.0, 2.0), DisplaySettings(diverging=True), "sRGB", lut)
    assert pixels[0, :, 0].tolist() == [0, 127, 254]
    builtin = diverging_lut(11)
    assert builtin[5].tolist() == [247, 247, 247] and builtin[0].tolist() == [5, 48, 97]


@pytest.mark.parametrize("settings", [DisplaySettings(channel="R"), DisplaySettings(channel="Y", normalisation="log"),
                                      DisplaySettings(diverging=True)])
def test_a_colour_bar_table_holds_the_colours_render_gives_from_low_to_high(settings):
    levels = (-2.0, 2.0) if settings.diverging else (0.01, 10.0)
    entries = 64
    if settings.diverging:
        values = np.linspace(-2.0, 2.0, entries)
    elif settings.normalisation == "log":
        values = np.geomspace(0.01, 10.0, entries)
    else:
        values = np.linspace(0.01, 10.0, entries)
    image = np.repeat(values[None, :, None], 3, axis=2).astype(np.float32)  # grey: Y equals each channel
    pixels = render(image, levels, settings).astype(int)
    assert np.abs(pixels[0] - scalar_lut(settings, entries=entries).astype(int)).max() <= 2


def test_scaled_difference_removes_the_least_squares_multiple_of_the_truth():
    rng = np.random.default_rng(2)
    truth = rng.uniform(0, 1, (6, 7, 3))
    transient = 3.5 * truth + rng.normal(0, 0.01, truth.shape)
    transient[0, 0, 0] = np.nan
    difference, scale = scaled_difference(transient, truth)
    finite = np.isfinite(transient)
    reference, *_ = np.linalg.lstsq(truth[finite][:, None], transient[finite], rcond=None)
    assert scale == pytest.approx(reference[0], rel=1e-12)
    np.testing.assert_allclose(difference[finite], transient[finite] - reference[0] * truth[finite], atol=1e-6)
    assert np.isnan(difference[0, 0, 0]) and np.isfinite(difference[finite]).all()
    empty, none = scaled_difference(transient, np.zeros_like(truth))
    assert math.isnan(none) and np.isnan(empty).all()


@pytest.mark.parametrize("antialias", [False, True])
def test_pixel_profile_equals_the_stack_at_every_point(dataset, antialias):
    radii = np.array([0.0, 0.5, 1.25, 2.0])
    stack = transient_stack(dataset, radii, step=0.75, thickness=1.25, antialias=antialias)
    rings = profile_rings(dataset, radii, 0.75, 1.25, antialias)
    for y in range(9):
        for x in range(10):
            profile = pixel_profile(dataset, rings, (y, x))
            np.testing.assert_allclose(profile.transient, stack.images[:, y, x], rtol=1e-5, atol=1e-6)
            assert np.array_equal(profile.counts, stack.counts[:, y, x])
            assert np.array_equal(profile.outer_counts, stack.outer_counts[:, y, x])


def test_pixel_profile_matches_brute_force(dataset, impulses):
    rings = profile_rings(dataset, [0.0, 1.0, 2.0], 1.0)
    profile = pixel_profile(dataset, rings, (4, 3))
    for index, radius in enumerate([0.0, 1.0, 2.0]):
        np.testing.assert_allclose(profile.ring[index], brute_ring_image(impulses, 9, 10, radius)[4, 3], rtol=1e-6)


def test_compute_stacks_share_rings_and_equal_the_separate_stacks(dataset):
    request = StackRequest(0.5, 2.0, 0.5, dr=0.25, thickness=1.0)
    pair = compute_stacks(dataset, request)
    ring = ring_stack(dataset, request.radii())
    transient = transient_stack(dataset, request.radii(), step=0.25)
    assert np.array_equal(pair.ring.images, ring.images, equal_nan=True)
    assert np.array_equal(pair.transient.images, transient.images, equal_nan=True)
    assert np.array_equal(pair.transient.outer_counts, transient.outer_counts)


def test_largest_stop_is_the_last_radius_whose_rings_fit(dataset):
    request = StackRequest(0.0, 0.0, 0.5, dr=1.0, thickness=1.0)
    stop = largest_stop(4.0, request)
    # Brute force: the ring at stop + dr has members up to the largest |d| < stop + dr + w/2.
    def reach(r):
        return max(math.hypot(dy, dx) for dy in range(-9, 10) for dx in range(-9, 10)
                   if r + 1.0 - 0.5 <= math.hypot(dy, dx) < r + 1.0 + 0.5)
    assert reach(stop) <= 4.0 < reach(stop + 0.5)
    assert default_request(4.0).stop == largest_stop(4.0, StackRequest(0.0, 0.0))
    with pytest.raises(StackError, match="largest stop is"):
        compute_stacks(dataset, request.with_changes(stop=stop + 0.5))


def test_largest_stop_equals_a_step_by_step_walk_and_refuses_steps_that_never_end():
    """The bisection against the walk it replaced (one step at a time until the rings reach past
    max_radius), on random grids; a step of 0 looped for good, a NaN step or thickness too."""
    def walk(max_radius, request):
        stop = request.start
        while True:
            candidate = round(stop + request.step, 9)
            if needed_radius([candidate], request.thickness, request.dr, request.antialias) > max_radius + 1e-9:
                return stop
            stop = candidate

    rng = np.random.default_rng(4)
    for _ in range(300):
        request = StackRequest(float(rng.choice([0.0, 0.5, 2.0])), 0.0, float(rng.choice([0.1, 0.25, 0.5, 1.0, 3.0])),
                               dr=float(rng.choice([0.5, 1.0, 2.0])), thickness=float(rng.choice([0.5, 1.0, 2.5])),
                               antialias=bool(rng.integers(2)))
        max_radius = float(rng.uniform(0.5, 40.0))
        assert largest_stop(max_radius, request) == walk(max_radius, request), (max_radius, request)
    for bad in ({"step": 0.0}, {"step": float("nan")}, {"thickness": 0.0}, {"dr": float("nan")}, {"start": -1.0}):
        with pytest.raises(StackError, match="must be"):
            largest_stop(12.0, StackRequest(0.0, 0.0).with_changes(**bad))


def test_nearest_bin_prefers_overlap_then_centre_distance():
    bounds = np.array([[0, 1], [1, 2], [2, 4], [4, 8]], np.float64)
    truth = PathLengthImages(bounds, np.zeros((4, 1, 1, 3), np.float32))
    assert truth.nearest_bin(1.0, 1.0) == 1
    assert truth.nearest_bin(1.5, 1.0) == 1  # [1.5, 2.5): overlaps bins 1 and 2 by 0.5; bin 1's centre is nearer
    assert truth.nearest_bin(2.0, 0.5) == 2
    assert truth.nearest_bin(20.0, 1.0) == 3  # no overlap: the nearest centre


def test_normalised_cross_correlation_equals_pearson_over_finite_entries():
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(6, 7, 3)), rng.normal(size=(6, 7, 3))
    a[0, 0, 0] = np.nan
    b[1, 1, 1] = np.inf
    both = np.isfinite(a) & np.isfinite(b)
    assert normalised_cross_correlation(a, b) == pytest.approx(np.corrcoef(a[both], b[both])[0, 1])
    assert normalised_cross_correlation(a, 3 * a + 1) == pytest.approx(1.0)
    assert math.isnan(normalised_cross_correlation(np.ones(5), np.arange(5.0)))


def test_movie_frames_carry_the_image_enlarged_and_the_label(tmp_path):
    frames = [np.full((20, 30, 3), value, np.uint8) for value in (30, 120, 220)]
    frames[1][:, :15] = (200, 40, 10)
    path = write_movie(tmp_path / "m.mp4", frames.__getitem__, ["r = 0", "r = 1", "r = 2"], 5.0)
    capture = cv2.VideoCapture(str(path))
    decoded = []
    while (result := capture.read())[0]:
        decoded.append(cv2.cvtColor(result[1], cv2.COLOR_BGR2RGB))
    capture.release()
    scale = movie_scale(30)
    assert len(decoded) == 3 and decoded[0].shape == (20 * scale, 30 * scale, 3)
    for frame, source in zip(decoded, frames):
        body = frame[frame.shape[0] // 2:]  # below the label
        expected = np.repeat(np.repeat(source, scale, 0), scale, 1)[frame.shape[0] // 2:]
        assert np.abs(body.astype(int) - expected).mean() < 4
    top_left = decoded[0][:40 * scale // 18, : 8 * scale]
    assert top_left.max() > 200  # the white label is burnt in over a dark (30) frame


def test_exports_refuse_bad_pixels_and_leave_nothing_when_cancelled(tmp_path):
    with pytest.raises(ExportError, match="uint8"):
        write_png(tmp_path / "x.png", np.zeros((4, 4, 3), np.float32))

    def cancel(fraction):
        if fraction > 0.3:
            raise Cancelled("cancelled")

    frames = [np.zeros((8, 8, 3), np.uint8)] * 5
    with pytest.raises(Cancelled):
        write_movie(tmp_path / "m.mp4", frames.__getitem__, ["a"] * 5, 10.0, cancel)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_negative_fraction_counts_finite_values_below_zero(dtype):
    rng = np.random.default_rng(4)
    image = rng.normal(size=(37, 41, 3)).astype(dtype)
    flat = image.reshape(-1)
    flat[rng.choice(flat.size, 300, replace=False)] = rng.choice([np.nan, np.inf, -np.inf, -0.0], 300)
    finite = np.isfinite(image)
    assert negative_fraction(image) == pytest.approx((image[finite] < 0).sum() / finite.sum(), rel=1e-12)
    assert negative_fraction(image[:, ::2]) == pytest.approx(  # a view that is not contiguous
        (image[:, ::2][finite[:, ::2]] < 0).sum() / finite[:, ::2].sum(), rel=1e-12)
    assert negative_fraction(np.full((2, 2, 3), np.nan, dtype)) == 0.0
