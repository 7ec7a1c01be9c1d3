"""The scatter of a batch of frames into a band's responses (core/dataset/scatter.py): frame by
frame for a small band, point by point otherwise; every point adds its frames in frame order, so
both give the same sums, bit for bit."""

from __future__ import annotations

import numpy as np
from ringlight.core.dataset import scatter


def batch(rng, frames, rows, width, offsets):
    """Weighed radiance (frames, rows, W, 3) float32 of both signs and owners (frames, rows, W)
    int16: about a third of the points take a slot, the others -1."""
    radiance = rng.normal(0, 1e3, (frames, rows, width, 3)).astype(np.float32)
    owner = rng.integers(0, offsets, (frames, rows, width)).astype(np.int16)
    owner[rng.random(owner.shape) < 0.65] = -1
    return radiance, owner


def brute_force(responses, steady, radiance, owner, count):
    """The scatter's definition, one frame, point and channel at a time in frame order: float32
    sums for the responses, float64 for the steady state."""
    for b in range(count):
        for (y, x), k in np.ndenumerate(owner[b]):
            if k >= 0:
                for c in range(3):
                    responses[y, x, k, c] = np.float32(responses[y, x, k, c] + radiance[b, y, x, c])
                    steady[y, x, c] += np.float64(radiance[b, y, x, c])


def test_a_small_band_scattered_frame_by_frame_sums_as_point_by_point_and_by_brute_force():
    rng = np.random.default_rng(7)
    rows, width, offsets = 4, 5, 7
    sums = {name: (np.zeros((rows, width, offsets, 3), np.float32), np.zeros((rows, width, 3)))
            for name in ("frames", "points", "brute force")}
    assert sum(array.nbytes for array in sums["frames"]) <= scatter.CACHED_BLOCKS  # scatter() goes frame by frame
    # Two batches into the same sums, the second with fewer frames than its arrays hold.
    for count in (60, 37):
        radiance, owner = batch(rng, 60, rows, width, offsets)
        scatter.scatter(*sums["frames"], radiance, owner, count)
        scatter._scatter_rows(*sums["points"], radiance, owner, count, 0, rows)  # the scatter for large bands
        brute_force(*sums["brute force"], radiance, owner, count)
    for name in ("points", "brute force"):
        assert sums["frames"][0].view(np.uint32).tobytes() == sums[name][0].view(np.uint32).tobytes(), name
        assert sums["frames"][1].view(np.uint64).tobytes() == sums[name][1].view(np.uint64).tobytes(), name
    assert np.count_nonzero(sums["frames"][0]) > rows * width * offsets  # most slots were reached


def test_blocks_put_in_offset_order_on_one_thread_and_in_parallel_are_numpys_take():
    """Offset k of each point's block is slot ``slot_of[k]``: numpy's fancy indexing is the
    reference, for the one-thread path (a small band) and the parallel one (called directly)."""
    rng = np.random.default_rng(3)
    slot_of = rng.permutation(11)
    responses = rng.normal(size=(3, 4, 11, 3)).astype(np.float32)
    expected = responses[:, :, slot_of]
    for order in (scatter.slots_to_offsets, scatter._offset_order):
        ordered = responses.copy()
        order(ordered, slot_of)
        assert np.array_equal(ordered, expected), order.__name__
