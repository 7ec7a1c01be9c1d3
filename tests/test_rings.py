"""Ring geometry: membership by the definition, exact anti-aliased areas."""

import doctest
import math

import numpy as np
import pytest
from ringlight.core import annulus_pixel_area, disc_offsets, ring_geometry
from ringlight.core.rings import geometry as rings
from ringlight.core.rings import stacks


@pytest.mark.parametrize("radius, thickness", [(0, 1), (1, 1), (2.5, 1), (7.3, 2), (10, 0.5), (0.2, 3)])
def test_default_ring_members_are_exactly_the_offsets_in_the_half_open_band(radius, thickness):
    ring = ring_geometry(radius, thickness)
    reach = int(radius + thickness) + 2
    expected = {
        (dy, dx)
        for dy in range(-reach, reach + 1)
        for dx in range(-reach, reach + 1)
        if radius - thickness / 2 <= math.hypot(dy, dx) < radius + thickness / 2
    }
    assert {tuple(o) for o in ring.offsets.tolist()} == expected
    assert (ring.weights == 1).all()


def test_ring_of_radius_one_has_the_eight_neighbours_and_radius_zero_the_centre():
    assert len(ring_geometry(1.0).offsets) == 8
    assert ring_geometry(0.0).offsets.tolist() == [[0, 0]]


@pytest.mark.parametrize("radius, thickness", [(0, 1), (0.3, 1), (1, 1), (4.5, 1), (12.25, 2.5), (30, 1)])
def test_antialiased_weights_sum_to_the_annulus_area(radius, thickness):
    ring = ring_geometry(radius, thickness, antialias=True)
    inner = max(radius - thickness / 2, 0.0)
    area = math.pi * ((radius + thickness / 2) ** 2 - inner ** 2)
    assert ring.weights.sum() == pytest.approx(area, rel=1e-12)
    assert (ring.weights > 0).all() and (ring.weights <= 1 + 1e-12).all()


def test_exact_pixel_areas_agree_with_fine_supersampling():
    rng = np.random.default_rng(0)
    samples = 1000
    u = (np.arange(samples) + 0.5) / samples - 0.5
    for _ in range(20):
        dy, dx = rng.integers(-6, 7, 2)
        inner, outer = sorted(rng.uniform(0, 7, 2))
        yy, xx = np.meshgrid(dy + u, dx + u, indexing="ij")
        distance = np.hypot(yy, xx)
        sampled = ((distance >= inner) & (distance < outer)).mean()
        # 10^6 samples: the boundary error is below ~1e-3 of a pixel.
        assert annulus_pixel_area(dy, dx, inner, outer) == pytest.approx(sampled, abs=2e-3)


def test_ring_around_a_centre_drops_members_outside_the_grid():
    positions, weights = ring_geometry(2.0).around((0, 1), (5, 5))
    expected = {
        (y, x) for y in range(5) for x in range(5) if 1.5 <= math.hypot(y - 0, x - 1) < 2.5
    }
    assert {tuple(p) for p in positions.tolist()} == expected
    assert len(weights) == len(positions)


def test_disc_offsets_hold_every_offset_within_the_radius():
    offsets = disc_offsets(3.0)
    assert len(offsets) == sum(1 for y in range(-3, 4) for x in range(-3, 4) if y * y + x * x <= 9)
    assert np.hypot(*offsets.T).max() == 3.0


def test_bad_ring_arguments_raise():
    with pytest.raises(ValueError, match="radius"):
        ring_geometry(-1)
    with pytest.raises(ValueError, match="thickness"):
        ring_geometry(1, 0)


@pytest.mark.parametrize("module", [rings, stacks])
def test_docstring_examples_run(module):
    failures, _ = doctest.testmod(module)
    assert failures == 0
