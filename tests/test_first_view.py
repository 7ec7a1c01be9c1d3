"""The view a dataset opens at (issue 39: the first screen was a white square): the radius, point
and levels chosen from the data, against per-pixel brute force and the scenes' true geometry."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest
from ringlight.core import open_dataset
from ringlight.core.colour.display import DisplaySettings, display_levels
from ringlight.core.colour.first_view import DISPLAY_STEP, first_view
from ringlight.core.colourspaces import colour_module
from ringlight.core.rings.stack_request import compute_stacks, default_request
from ringlight.core.simulate.samples import sample_dataset


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path / "cache"))


def sample_stack(name, link_sample):
    link_sample(name)  # as sample_dataset writes it, written once for the whole run
    dataset = open_dataset(sample_dataset(name))
    return dataset, compute_stacks(dataset, default_request(dataset.max_radius)).transient


def luminance_weights(colorspace):
    """Y of linear RGB: the second row of colour-science's RGB -> XYZ matrix."""
    return colour_module().RGB_COLOURSPACES[colorspace].matrix_RGB_to_XYZ[1]


def brute_contrast_and_noise(image, counts, outer_counts, weights):
    """The module's definitions, pixel by pixel: robust range of the 3 x 3 mean over fully covered
    points / median, and 1.4826 x MAD of (value - 3 x 3 mean) / median."""
    height, width = counts.shape
    luminance = [[float(np.dot(image[y, x], weights)) for x in range(width)] for y in range(height)]
    full = [[np.isfinite(luminance[y][x]) and counts[y, x] == counts.max() and outer_counts[y, x] == outer_counts.max()
             for x in range(width)] for y in range(height)]
    values, means = [], []
    for y in range(height):
        for x in range(width):
            if not full[y][x]:
                continue
            window = [luminance[j][i] for j in range(y - 1, y + 2) for i in range(x - 1, x + 2)
                      if 0 <= j < height and 0 <= i < width and full[j][i]]
            values.append(luminance[y][x])
            means.append(sum(window) / len(window))
    values, means = np.array(values), np.array(means)
    median = np.median(values)
    residual = values - means
    mad = np.median(np.abs(residual - np.median(residual)))
    return (np.percentile(means, 99) - np.percentile(means, 1)) / median, 1.4826 * mad / median


def test_contrast_and_noise_per_radius_equal_brute_force_on_the_red_bead_sample(link_sample):
    dataset, stack = sample_stack("red-bead", link_sample)
    view = first_view(stack.images, stack.counts, stack.outer_counts, dataset.colorspace)
    weights = luminance_weights(dataset.colorspace)
    expected = np.array([brute_contrast_and_noise(stack.images[i], stack.counts[i], stack.outer_counts[i], weights)
                         for i in range(len(stack.radii))])
    np.testing.assert_allclose(view.contrast, expected[:, 0], rtol=1e-4)
    np.testing.assert_allclose(view.noise, expected[:, 1], rtol=1e-3, atol=1e-7)
    ratio = expected[:, 0] / np.maximum(expected[:, 1], DISPLAY_STEP)
    assert view.radius_index == int(np.argmax(ratio))


def test_the_red_bead_opens_on_the_bead_at_a_radius_where_it_stands_out(link_sample):
    dataset, stack = sample_stack("red-bead", link_sample)
    view = first_view(stack.images, stack.counts, stack.outer_counts, dataset.colorspace)
    scene = json.loads(resources.files("ringlight.resources.scenes").joinpath("red-bead.json").read_text())
    height, width = dataset.grid_shape
    centre_y, centre_x, _ = scene["shapes"][0]["center"]
    # The sample is the scene rescaled to the bundled grid: positions scale with it.
    true_y = centre_y * height / scene["grid"]["height"]
    true_x = centre_x * width / scene["grid"]["width"]
    assert np.hypot(view.pick[0] - true_y, view.pick[1] - true_x) <= 1.5, (view.pick, true_y, true_x)
    assert view.structured and view.normalisation == "range"
    assert stack.radii[view.radius_index] > 0  # T_0 is the nearly uniform white square of the issue
    assert view.contrast[view.radius_index] > 10 * view.contrast[0]


@pytest.mark.parametrize("name", ["layers3", "skin1"])
def test_layered_samples_have_no_lateral_structure_and_keep_the_robust_maximum(name, link_sample):
    dataset, stack = sample_stack(name, link_sample)
    view = first_view(stack.images, stack.counts, stack.outer_counts, dataset.colorspace)
    assert not view.structured
    assert (view.radius_index, view.pick, view.normalisation) == (0, (24, 24), "per-image")


def test_a_disc_that_stands_out_most_at_one_radius_is_shown_there_and_picked_at_its_centre():
    """Five radii over a 40 x 40 grid of value 1: a disc of radius 5 centred at (12, 27) with
    relative contrast 0, 0.1, 0.3, 0.5, 0.6 and white noise of relative sigma 0, 0.002, 0.01,
    0.05, 0.2: contrast / noise peaks at index 2 (0.3 / 0.01 = 30; 0.5 / 0.05 = 10)."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:40, :40]
    disc = np.hypot(yy - 12, xx - 27) <= 5
    images = np.empty((5, 40, 40, 3), np.float32)
    for index, (contrast, sigma) in enumerate(zip([0, 0.1, 0.3, 0.5, 0.6], [0, 0.002, 0.01, 0.05, 0.2])):
        base = 1.0 + contrast * disc + sigma * rng.standard_normal((40, 40))
        images[index] = base[..., None]
    counts = np.full((5, 40, 40), 8, np.int32)
    view = first_view(images, counts, counts)
    assert view.radius_index == 2 and view.pick == (12, 27) and view.structured


def test_uniform_noise_alone_is_not_taken_for_structure():
    rng = np.random.default_rng(5)
    images = (1.0 + 0.05 * rng.standard_normal((4, 30, 30, 1))).repeat(3, axis=-1).astype(np.float32)
    counts = np.ones((4, 30, 30), np.int32)
    view = first_view(images, counts, counts)
    assert not view.structured
    assert np.all(view.contrast_to_noise < 5)


def test_range_levels_are_the_robust_minimum_and_maximum():
    """201 values 0..200: the 0.5th and 99.5th percentiles fall on the values 1 and 199."""
    values = np.random.default_rng(1).permutation(np.arange(201, dtype=np.float32)).reshape(67, 1, 3)
    assert display_levels(values, DisplaySettings(normalisation="range")) == (1.0, 199.0)
    flat = np.full((4, 4, 3), 0.5, np.float32)  # no range: the robust maximum's (0, max)
    assert display_levels(flat, DisplaySettings(normalisation="range")) == (0.0, 0.5)
    signed = DisplaySettings(normalisation="range", diverging=True)  # a diverging view stays symmetric
    assert display_levels(values, signed)[0] == -display_levels(values, signed)[1]
