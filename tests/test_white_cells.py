"""The white run tallied into cells (ringlight.core.inversion.white_cells) against the records of the
same photons summed exactly, finite differences, the records' own per-photon variance, and the
direct simulator; and its user cache."""

from __future__ import annotations

import os

import numpy as np
import pytest

from ringlight.core.inversion.forward import Forward, Structure
from ringlight.core.inversion.cell_forward import CellForward
from ringlight.core.inversion.white_cells import (
    BATCHES,
    CellDatabase,
    cell_database,
    cells_path,
    pixel_classes,
    run_cells,
)
from ringlight.core.inversion.white_mc import DatabaseError, SlabOptics, run_white

from reference import assert_slopes_are_central_differences
from test_inversion import MUA, MUS, RADII, TOPS, direct_profile

# layers3's slab: two weakly scattering layers over a base that scatters three times as much.
OPTICS = SlabOptics((0.5, 0.5, 0.5, 0.5, 0.5, 1.5), 0.0, 1.3, 24.0, 13)
STRUCTURE = Structure((0, 2, 5))
PHOTONS = 6400
SEED = 3


@pytest.fixture(scope="module")
def cells():
    return run_cells(OPTICS, STRUCTURE, PHOTONS, SEED)


@pytest.fixture(scope="module")
def records():
    """The records of the very photons the cells hold (run_cells's chunks and seeds run again):
    each record's pixel class, value and path length per layer, and the photon count."""
    classes = pixel_classes(OPTICS.reach)
    parts, photons = [], 0
    for chunk in range(BATCHES):  # PHOTONS fill one chunk per batch
        run = run_white(OPTICS, -(-PHOTONS // BATCHES), SEED + (chunk << 32))
        photons += run.photons
        lengths = np.add.reduceat(run.lengths, np.asarray(STRUCTURE.starts), axis=1, dtype=np.float64)
        parts.append((classes[run.pixel], run.value.astype(np.float64), lengths))
    return [np.concatenate(column) for column in zip(*parts)], photons


def records_profile(records, forward: CellForward, mua: np.ndarray) -> np.ndarray:
    """E(r) by brute force: each record's ``v exp(-a . l)`` summed per pixel class, exactly."""
    (classes, values, lengths), photons = records
    weights = values * np.exp(-(lengths @ mua))
    return forward.rings @ np.bincount(classes, weights, forward.rings.shape[1]) / photons


def test_a_pixel_class_holds_the_offsets_the_squares_symmetries_map_onto_each_other():
    classes = pixel_classes(3).reshape(7, 7)
    for dy in range(-3, 4):
        for dx in range(-3, 4):
            images = {(dy, dx), (-dy, dx), (dy, -dx), (-dy, -dx), (dx, dy), (-dx, dy), (dx, -dy), (-dx, -dy)}
            assert {classes[y + 3, x + 3] for y, x in images} == {classes[dy + 3, dx + 3]}
    # and offsets no symmetry relates (equal distance, (0, 5) and (3, 4)) stay apart
    assert pixel_classes(5).reshape(11, 11)[5, 10] != pixel_classes(5).reshape(11, 11)[8, 9]


def test_cells_stand_for_their_records_to_0_03_percent_below_absorption_0_5(cells, records):
    """The error the tally adds: against the exact sum of the same records, at most 3e-4 of E(r),
    r = 0..11, for absorptions up to 0.5 per grid step in every layer, and 2e-2 up to 3."""
    forward = CellForward(cells, STRUCTURE, np.arange(0.0, 12.0))
    rng = np.random.default_rng(8)
    for high, tolerance in ((0.5, 3e-4), (3.0, 2e-2)):
        for _ in range(4):
            mua = np.exp(rng.uniform(np.log(1e-3), np.log(high), 3))
            np.testing.assert_allclose(forward.profile(mua), records_profile(records, forward, mua), rtol=tolerance)
    assert cells.photons == records[1]


def test_cells_hold_a_fraction_of_their_records(cells, records):
    assert len(cells.weight) < 0.5 * len(records[0][0])


def test_cell_derivatives_match_finite_differences(cells):
    assert_slopes_are_central_differences(CellForward(cells, STRUCTURE, RADII), np.array([0.05, 0.2, 0.01]))


@pytest.mark.parametrize("layers", [1, 2, 3, 4])
def test_the_cell_kernels_sum_each_cells_formula_as_numpy_does(layers):
    """The compiled kernels (cells sorted by class, columns padded to four layers, classes no ring
    weighs dropped, vectorised with their exp written out) against ``W exp(-a . mu) (1 + a^T S a /
    2)`` and its derivatives summed over every cell in numpy: equal to 1e-10, with means and covariances rounded to float32 as the
    kernels store them; the batches' covariance likewise."""
    rng = np.random.default_rng(layers)
    count = 3000
    classes = pixel_classes(OPTICS.reach)
    spread = rng.uniform(-0.2, 1.0, (count, layers, layers))
    spread = 0.5 * (spread + spread.transpose(0, 2, 1))
    database = CellDatabase(OPTICS, tuple(range(layers)), 5000, rng.integers(0, classes.max() + 1, count),
                            rng.uniform(0.1, 2.0, count), rng.uniform(0.0, 30.0, (count, layers)), spread,
                            rng.uniform(0.0, 0.2, (BATCHES, count)).astype(np.float32), 0.0)
    radii = np.arange(0.0, 6.0)  # rings that weigh only some of the classes
    forward = CellForward(database, Structure(tuple(range(layers))), radii)
    mean = database.mean.astype(np.float32).astype(np.float64)
    spread = database.spread.astype(np.float32).astype(np.float64)
    mua = rng.uniform(0.001, 0.2, layers)
    turned = spread @ mua  # (M, L) S a
    correction = 1.0 + 0.5 * turned @ mua
    kept = database.weight * np.exp(-(mean @ mua))
    per_class = lambda values: np.bincount(database.cell_class, values, forward.rings.shape[1])
    profile = forward.rings @ per_class(kept * correction) / database.photons
    slopes = np.stack([forward.rings @ per_class(kept * (turned[:, k] - mean[:, k] * correction))
                       for k in range(layers)], axis=1) / database.photons
    fitted, derivatives = forward.profile(mua, derivatives=True)
    np.testing.assert_allclose(fitted, profile, rtol=1e-10)
    np.testing.assert_allclose(derivatives, slopes, rtol=1e-10, atol=1e-10 * np.abs(slopes).max())
    batches = np.stack([forward.rings @ per_class(database.batch_weight[b] * np.exp(-(mean @ mua)) * correction)
                        for b in range(BATCHES)]) * (BATCHES / database.photons)
    centred = batches - batches.mean(axis=0)
    np.testing.assert_allclose(forward.variance(mua), (centred ** 2).sum(axis=0) / (BATCHES - 1) / BATCHES,
                               rtol=1e-6)


def test_the_batches_variance_matches_the_records_per_photon_variance():
    """The white run's own variance from the cells' 16 batches against the records' per-photon
    variance of a run of as many photons: their standard deviations agree on average over the
    rings within 20 % (a spread of 16 batches is itself uncertain by about 18 % per ring)."""
    cells = run_cells(OPTICS, STRUCTURE, 32_000, seed=4)
    records = Forward(run_white(OPTICS, 32_000, seed=5), STRUCTURE, RADII)
    forward = CellForward(cells, STRUCTURE, RADII)
    for mua in (np.array([0.004, 0.01, 0.3]), np.array([0.25, 0.02, 0.004])):
        ratio = np.sqrt(forward.variance(mua) / records.variance(mua))
        assert 0.8 < ratio.mean() < 1.2, ratio


def test_a_cells_profile_equals_the_direct_simulator_within_three_standard_errors():
    """test_inversion's three-layer slab (different scattering per layer, g 0.5, Fresnel) by the
    direct simulator, its own walks with absorption: every ring of every channel within three
    combined standard errors."""
    optics = SlabOptics((0.8, 0.8, 0.8, 0.8, 2.0), 0.5, 1.4, 24.0, 13)
    structure = Structure(tuple(TOPS))
    forward = CellForward(run_cells(optics, structure, 40_000, seed=6), structure, RADII)
    mean, error = direct_profile(MUS, MUA, TOPS, 0.5, 1.4, 24.0, 40_000, seed=12)
    for c in range(3):
        mua = np.array([MUA[layer][c] for layer in range(3)])
        model = forward.profile(mua)
        combined = np.sqrt(error[:, c] ** 2 + forward.variance(mua))
        assert np.all(np.abs(model - mean[:, c]) < 3 * combined), (c, (model - mean[:, c]) / combined)


def test_a_cell_database_is_cached_read_back_whole_and_run_again_when_damaged(tmp_path, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path))
    made = cell_database(OPTICS, STRUCTURE, 1000)
    path = cells_path(OPTICS, STRUCTURE, 1000, 0)
    again = cell_database(OPTICS, STRUCTURE, 1000)
    for name in ("cell_class", "weight", "mean", "spread", "batch_weight"):
        np.testing.assert_array_equal(getattr(again, name), getattr(made, name))
    path.write_bytes(path.read_bytes()[:300])  # truncated: run again and replaced
    rerun = cell_database(OPTICS, STRUCTURE, 1000)
    np.testing.assert_array_equal(rerun.weight, made.weight)
    assert cell_database(OPTICS, STRUCTURE, 1000).weight.shape == made.weight.shape
    path.unlink()
    os.mkfifo(path)  # read, a FIFO would block for good: one line instead
    with pytest.raises(DatabaseError, match="not a white Monte Carlo database"):
        cell_database(OPTICS, STRUCTURE, 1000)
