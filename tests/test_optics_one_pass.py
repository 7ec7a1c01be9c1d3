"""The maps' one pass (each row's rings, their spread, then its fits) against the same steps
taken apart: the stack and its errors over the whole grid, then the fits of every pixel."""

from dataclasses import replace

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS, model_dataset
from ringlight.core import Cancelled
from ringlight.core.optics import radial
from ringlight.core.optics.maps import MODEL_FLOOR, error_freedom, profile_radii, t_inflation
from ringlight.core.optics.one_pass import fit_in_one_pass
from ringlight.core.optics.pixel_fit import fit_profiles
from ringlight.core.optics.table import build_table
from ringlight.core.rings.stack_spread import ring_stack_and_errors


@pytest.fixture(scope="module")
def dataset():
    run = radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0)
    # Wider than a chunk (chunk_fit.CHUNK, 64 pixels): fits carry their start across chunks, and the
    # rings cut by the right edge are checked member by member in the second chunk.
    dataset = model_dataset(run, 0.5, 0.02, 70, 6, noise=np.full(7, 0.03), seed=4)
    observed = dataset.observed.copy()
    observed[20, 7:9] = False  # no data there: NaN, and the next fits start afresh
    observed[30, 63:65] = False  # across the chunks' boundary
    return replace(dataset, observed=observed), run


def test_one_pass_equals_the_stack_then_the_fits(dataset):
    dataset, run = dataset
    radii = profile_radii(dataset)
    table = build_table(run, radii)
    inflation = t_inflation(error_freedom(dataset, radii, "ring spread"))
    scale = np.array([1.0, 0.9, 1.1])
    fitted, complete = fit_in_one_pass(dataset, radii, table, scale, MODEL_FLOOR, inflation)
    # The reference: the stack and its errors in a pass of their own, then the maps' fits.
    stack, errors = ring_stack_and_errors(dataset, radii)
    expected = fit_profiles(table, stack.images, errors, scale, counts=stack.counts, floor=MODEL_FLOOR,
                            inflation=inflation, estimator="nodes")
    for name in ("rings", "status", "node_steps"):
        np.testing.assert_array_equal(fitted[name], expected[name])
    assert (fitted["status"][20, 7:9] == 1).all() and (fitted["status"][30, 63:65] == 1).all()
    assert (fitted["node_steps"] > 0).mean() > 0.9
    # The same fits; the compiler may order their sums differently (reassociation) in each.
    for name, deviation in (("u", "cuu"), ("v", "cvv")):
        np.testing.assert_allclose(fitted[name], expected[name], rtol=0,
                                   atol=1e-9 * np.nanmin(np.sqrt(expected[deviation])), equal_nan=True)
    for name in ("cuu", "cuv", "cvv", "chi2"):
        np.testing.assert_allclose(fitted[name], expected[name], rtol=1e-9, atol=1e-15, equal_nan=True)
    whole = np.array([1, 8, 12, 16, 32, 28])  # members of rings 0..5 (disc offsets by distance)
    np.testing.assert_array_equal(complete, (stack.counts == whole[:, None, None]).all(axis=0))
    assert complete.sum() == 60 * 60 - 4 and not complete[20, 7]  # rings to 5 steps from the edges


def test_cancel_stops_the_pass(dataset):
    dataset, run = dataset
    radii = profile_radii(dataset)
    with pytest.raises(Cancelled):
        fit_in_one_pass(dataset, radii, build_table(run, radii), np.ones(3), MODEL_FLOOR, np.ones(len(radii)),
                        cancelled=lambda: True)
