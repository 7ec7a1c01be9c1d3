"""ringlight.core.inversion.vector_exp against the C library's exp (Python's math.exp)."""

from __future__ import annotations

import math

import numba
import numpy as np

from ringlight.core.inversion.vector_exp import HIGHEST, LOWEST, vector_exp


@numba.njit
def _plain_loop(x):
    out = np.empty_like(x)
    for i in range(len(x)):
        out[i] = vector_exp(x[i])
    return out


@numba.njit(fastmath={"reassoc", "contract"})
def _fast_math_loop(x):
    """As the cell kernel calls it: from a loop whose sums may be reassociated."""
    out = np.empty_like(x)
    total = 0.0
    for i in range(len(x)):
        out[i] = vector_exp(x[i])
        total += out[i]
    return out, total


def _ulps(values: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.abs(values - reference) / np.spacing(reference)


def test_vector_exp_is_math_exp_to_one_unit_in_the_last_place():
    """Within one unit in the last place of math.exp over the whole range, from a plain loop and
    from a fast-math one (where a reassociated range reduction had been 211 units off near 700)."""
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.uniform(-1.0, 1.0, 20_000), rng.uniform(LOWEST, HIGHEST, 20_000),
                        np.linspace(LOWEST, HIGHEST, 5001), [0.0, -0.0, 1e-300, -1e-300, LOWEST, HIGHEST]])
    reference = np.array([math.exp(value) for value in x])
    assert _ulps(_plain_loop(x), reference).max() <= 1.0
    fast, _ = _fast_math_loop(x)
    assert _ulps(fast, reference).max() <= 1.0
    _, total = _fast_math_loop(x[:20_000])
    assert math.isclose(total, math.fsum(reference[:20_000]), rel_tol=1e-13)


def test_vector_exp_is_zero_below_its_range_infinite_above_and_nan_for_nan():
    x = np.array([LOWEST - 1e-9, -745.2, -1e6, -np.inf, HIGHEST + 1e-9, 1e6, np.inf, np.nan])
    values = _plain_loop(x)
    np.testing.assert_array_equal(values[:4], 0.0)
    np.testing.assert_array_equal(values[4:7], np.inf)
    assert np.isnan(values[7])
    assert vector_exp(0.0) == 1.0 and vector_exp(1.0) == math.exp(1.0)
