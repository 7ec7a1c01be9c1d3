"""The one-pass ring images and ring-spread errors against the stack and the noise module's
separate passes, and against the definition by brute force."""

from dataclasses import replace

import numpy as np
import pytest
from reference import random_impulses, write_dataset
from ringlight.core import open_dataset
from ringlight.core.errors import StackError
from ringlight.core.rings.noise import stack_noise
from ringlight.core.rings.stack_spread import ring_stack_and_errors
from ringlight.core.rings.stacks import ring_stack
from test_noise import brute_ring_se


def random_dataset_with(tmp_path_factory, missing):
    rng = np.random.default_rng(5)
    height, width = 10, 11
    impulses = random_impulses(rng, height, width, support=4.0, missing=missing)
    folder = tmp_path_factory.mktemp("spread") / "random"
    write_dataset(folder, height, width, impulses, max_radius=4.0)
    return impulses, open_dataset(folder, use_cache=False)


@pytest.fixture(scope="module")
def random_dataset(tmp_path_factory):
    # Missing lit points and the grid's edges cut rings: the kernel's path that checks members.
    return random_dataset_with(tmp_path_factory, 0.15)


@pytest.fixture(scope="module")
def lit_dataset(tmp_path_factory):
    # Every point lit: the pixels 3 or more from the edges have whole rings to r = 2 (no checks).
    return random_dataset_with(tmp_path_factory, 0.0)


@pytest.mark.parametrize("name", ["random_dataset", "lit_dataset"])
def test_one_pass_equals_the_stack_and_its_ring_spread(name, request):
    _, dataset = request.getfixturevalue(name)
    radii = np.arange(3.0)  # stack_noise also reads each ring's next one (r + 1 <= 3)
    stack, errors = ring_stack_and_errors(dataset, radii)
    if name == "lit_dataset":
        assert (stack.counts[:, 3:-3, 3:-3] == np.array([1, 8, 12])[:, None, None]).all()
    expected = ring_stack(dataset, radii)
    np.testing.assert_array_equal(stack.counts, expected.counts)
    np.testing.assert_allclose(stack.images, expected.images, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(errors, stack_noise(dataset, radii).ring, rtol=2e-5, atol=1e-9, equal_nan=True)
    assert np.isnan(errors[0]).all()  # one member at r = 0: no spread


def test_one_pass_errors_equal_the_definition(random_dataset):
    impulses, dataset = random_dataset
    height, width = dataset.grid_shape
    _, errors = ring_stack_and_errors(dataset, [2.0])
    se, _ = brute_ring_se(impulses, height, width, 2.0)
    np.testing.assert_allclose(errors[0], se, rtol=2e-5, atol=1e-9, equal_nan=True)


def test_unobserved_points_are_nan(random_dataset):
    _, dataset = random_dataset
    observed = dataset.observed.copy()
    observed[3, 4] = False
    blind = replace(dataset, observed=observed)
    stack, errors = ring_stack_and_errors(blind, [1.0, 2.0])
    assert np.isnan(stack.images[:, 3, 4]).all() and np.isnan(errors[:, 3, 4]).all()
    assert (stack.counts[:, 3, 4] == 0).all()
    np.testing.assert_allclose(errors, stack_noise(blind, [1.0, 2.0]).ring, rtol=2e-5, atol=1e-9, equal_nan=True)


def test_rings_beyond_max_radius_are_refused(random_dataset):
    _, dataset = random_dataset
    with pytest.raises(StackError, match="max_radius"):
        ring_stack_and_errors(dataset, [4.0])
