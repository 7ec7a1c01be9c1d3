"""The maps' node fits a chunk at a time (pixels as the lanes of vectorised loops) against the same
rules taken pixel by pixel: the rings' weights against :func:`pixel_profile`, and each pixel's fit
against :func:`node_steps` from the chunk's start."""

import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS
from ringlight.core.optics import radial
from ringlight.core.optics.chunk_fit import CHUNK, chunk_scratch, node_fit_chunk
from ringlight.core.optics.maps import MODEL_FLOOR
from ringlight.core.optics.node_fit import fine_nodes, node_steps
from ringlight.core.optics.pixel_data import chunk_profiles, pixel_profile, row_scratch
from ringlight.core.optics.pixel_fit import CONVERGED, coarse_nodes, fit_outputs
from ringlight.core.optics.table import build_table

RINGS = 8
MEMBERS = np.array([1, 8, 12, 16, 32, 28, 40, 40])


@pytest.fixture(scope="module")
def table():
    return build_table(radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0), np.arange(8.0))


def chunk(table, noise, seed, pixels=CHUNK):
    """(3, R, CHUNK) float32 lanes of E and their standard errors (ring 0 without one, as the ring
    spread gives it), a medium per channel, relative Gaussian ``noise``; and (R, 1, pixels) members."""
    rng = np.random.default_rng(seed)
    truth = np.stack([table.profile(mus, mua) for mus, mua in [(0.5, 0.02), (0.15, 0.005), (1.2, 0.1)]])
    errors = noise * truth[:, :, None] / np.sqrt(MEMBERS[None, :, None]) * np.ones((1, 1, CHUNK))
    lanes = truth[:, :, None] + errors * rng.standard_normal((3, RINGS, CHUNK))
    errors = errors * np.sqrt(rng.chisquare(6, errors.shape) / 6)
    errors[:, 0] = np.nan
    counts = np.broadcast_to(MEMBERS[:, None, None], (RINGS, 1, pixels)).astype(np.int32).copy()
    return lanes.astype(np.float32), errors.astype(np.float32), counts


def pixel_by_pixel(lanes, errors, errors_given, counts, inflation, pixels):
    """(data, weight (C, R, CHUNK), used (C, CHUNK)) of each pixel by :func:`pixel_profile`."""
    measured = lanes.transpose(1, 2, 0)[:, None]  # (R, 1, CHUNK, C)
    sigma = errors.transpose(1, 2, 0)[:, None]
    _, variance, one_data, one_weight, _, _ = row_scratch(RINGS)
    data, weight = np.zeros(lanes.shape), np.zeros(lanes.shape)
    used = np.zeros(lanes.shape[::2], np.int64)
    for c in range(lanes.shape[0]):
        for x in range(pixels):
            used[c, x] = pixel_profile(measured, sigma, errors_given, counts, inflation, MODEL_FLOOR, 0, x, c,
                                       variance, one_data, one_weight)
            data[c, :, x], weight[c, :, x] = one_data, one_weight
    return data, weight, used


@pytest.mark.parametrize("errors_given", [True, False])
def test_chunk_weights_are_each_pixels_to_the_bit_and_flag_what_only_a_pixel_can_borrow(table, errors_given):
    lanes, errors, counts = chunk(table, 0.03, seed=3)
    lanes[0, 4, 5] = np.nan  # a ring without data: weight 0
    lanes[1, 3, 6] = 0.0  # E = 0: ring 3 borrows its error from ring 2 (irregular)
    errors[2, 1, 7] = np.nan  # ring 0 cannot borrow from ring 1: from ring 2 (irregular)
    errors[0, 6, 8] = -1.0  # a deviation that is not positive (without errors given: weight 0)
    lanes[1, :, 9] = np.nan  # no data at all
    counts[1, 0, 10] = 5  # ring 1 cut: ring 0's borrowed error is scaled by sqrt(5 / 1), not sqrt(8 / 1)
    counts[0, 0, 11] = 0  # ring 0 cut: its error would be borrowed over max(0, 1) members
    inflation = np.linspace(1.0, 1.4, RINGS)
    pixels = CHUNK - 3  # the last lanes are not the chunk's
    data, weight = np.empty((3, RINGS, CHUNK)), np.empty((3, RINGS, CHUNK))
    used, irregular = np.empty((3, CHUNK), np.int64), np.empty((3, CHUNK), np.int64)
    chunk_profiles(lanes, errors, errors_given, counts[:, :, :pixels], inflation, MODEL_FLOOR, pixels, data, weight,
                   used, irregular)
    expected = pixel_by_pixel(lanes, errors, errors_given, counts[:, :, :pixels], inflation, pixels)
    regular = irregular[:, :pixels] == 0
    flagged = {(int(c), int(x)) for c, x in zip(*np.nonzero(~regular))}
    assert flagged == ({(1, 6), (2, 7)} if errors_given else set())
    for got, want in zip((data, weight), expected[:2]):
        np.testing.assert_array_equal(got[:, :, :pixels].transpose(0, 2, 1)[regular],
                                      want[:, :, :pixels].transpose(0, 2, 1)[regular])
    np.testing.assert_array_equal(used[:, :pixels][regular], expected[2][:, :pixels][regular])
    assert used[1, 9] == 0 and weight[0, 4, 5] == 0.0
    if errors_given:  # ring 0's borrowed error by hand: ring 1's relative error times sqrt(its members / ring 0's)
        for x, members in ((10, 5.0), (11, 8.0), (12, 8.0)):
            image = float(lanes[0, 0, x])
            relative = float(errors[0, 1, x]) * inflation[1] / float(lanes[0, 1, x])
            variance = (image * relative) ** 2 * members + (MODEL_FLOOR * image) ** 2
            assert weight[0, 0, x] == pytest.approx(1 / variance, rel=1e-13)


def fit_chunk(table, lanes, errors, counts, starts, pixels=CHUNK):
    """``node_fit_chunk`` of one chunk into fresh outputs; returns them and the starts after it."""
    out = fit_outputs(1, pixels, 3)
    starts = starts.copy()
    node_fit_chunk(*fine_nodes(table), table.log_profile, coarse_nodes(table.log_profile), table.u0, table.du,
                   table.v0, table.dv, lanes, errors, pixels, np.ones(3), True, counts, MODEL_FLOOR, np.ones(RINGS), 0,
                   0, starts, out["u"], out["v"], out["cuu"], out["cuv"], out["cvv"], out["chi2"], out["rings"],
                   out["status"], out["node_steps"], chunk_scratch(3, RINGS))
    return out, starts


@pytest.mark.parametrize("noise", [0.01, 0.05])
def test_each_lane_is_the_pixels_own_fit_from_the_chunks_start(table, noise):
    lanes, errors, counts = chunk(table, noise, seed=int(noise * 100))
    lanes[:, :, 30] = lanes[::-1, :, 30]  # channels 0 and 2 swap media: their first step lands far
    errors[:, :, 30] = errors[::-1, :, 30]
    # The chunk's start: a fit of its own first pixel, as the previous chunk's last would give it.
    first, _ = fit_chunk(table, lanes, errors, counts[:, :, :1], np.full((3, 2), np.nan), pixels=1)
    start = np.stack([first["u"][0, 0], first["v"][0, 0]], axis=1)
    out, after = fit_chunk(table, lanes, errors, counts, start)
    assert (out["status"] == CONVERGED).all()
    data, weight, _ = pixel_by_pixel(lanes, errors, True, counts, np.ones(RINGS), CHUNK)
    fitted = np.empty(6)
    nodes = fine_nodes(table)
    for c in range(3):
        for x in range(CHUNK):
            taken = node_steps(*nodes, np.ascontiguousarray(data.transpose(0, 2, 1)),
                               np.ascontiguousarray(weight.transpose(0, 2, 1)), c, x, 1.0, start[c, 0], start[c, 1], 0,
                               fitted)
            assert taken == out["node_steps"][0, x, c]
            if taken == 0:
                continue  # the full fit's, as the pixel alone would give it
            for i, name in enumerate(("u", "v")):
                se = np.sqrt(fitted[2 + 2 * i])
                assert abs(out[name][0, x, c] - fitted[i]) < 1e-9 * se
            np.testing.assert_allclose([out[name][0, x, c] for name in ("cuu", "cuv", "cvv", "chi2")], fitted[2:],
                                       rtol=1e-9, atol=1e-15)
    steps = out["node_steps"][0]
    # Most lanes take the chunk's steps (the rest their own); the other media's lanes are fitted alone.
    assert (steps == 1).mean() > 0.8 and (steps[30, [0, 2]] != 1).all()
    np.testing.assert_array_equal(after, np.stack([out["u"][0, -1], out["v"][0, -1]], axis=1))


def test_a_chunk_without_a_start_fits_its_first_pixels_alone_until_one_converges(table):
    lanes, errors, counts = chunk(table, 0.03, seed=9)
    lanes[0, :, :2] = np.nan  # channel 0's first two pixels have no data: the third starts the chunk
    out, after = fit_chunk(table, lanes, errors, counts, np.full((3, 2), np.nan))
    steps = out["node_steps"][0]
    np.testing.assert_array_equal(steps[:3, 0], [0, 0, 0])
    np.testing.assert_array_equal(steps[0, 1:], [0, 0])  # channels 1 and 2: their first pixel
    assert (steps[3:, 0] >= 1).all() and (steps[1:, 1:] >= 1).all()
    np.testing.assert_array_equal(out["status"][0, :2, 0], [1, 1])  # NO_DATA
    assert np.isfinite(after).all()


def test_a_start_at_the_tables_edge_gives_one_full_fit_and_the_rest_node_steps(table):
    # A start within two fine nodes of the table's edge takes no chunk step: the first pixel is the
    # full fit, and each next pixel steps from the last one's minimum (not the edge's start again,
    # which made every pixel of the chunk a full fit).
    lanes, errors, counts = chunk(table, 0.03, seed=11)
    _, node_u0, node_du, node_v0, node_dv = fine_nodes(table)
    edge = np.array([[node_u0 + node_du, node_v0 + 40 * node_dv]] * 3)
    out, _ = fit_chunk(table, lanes, errors, counts, edge)
    steps = out["node_steps"][0]
    assert (out["status"] == CONVERGED).all()
    np.testing.assert_array_equal(steps[0], [0, 0, 0])
    assert (steps[1:] >= 1).all()
