"""The compact camera mapping (issue 19, memory for big cameras): int32 indices, no float64 copy
of a frame, and the same grid values as FORMAT.md's definition computed by brute force."""

import tracemalloc

import numpy as np
from ringlight.core.dataset.frames import CameraMapping


def brute_force_grid(image, y, x, grid_shape):
    """FORMAT.md: grid [gy, gx] is the mean of the camera pixels whose rounded position
    (floor(v + 0.5)) is [gy, gx]; NaN where none is."""
    sums = np.zeros((*grid_shape, image.shape[-1]))
    counts = np.zeros(grid_shape)
    for row in range(image.shape[0]):
        for col in range(image.shape[1]):
            if not (np.isfinite(y[row, col]) and np.isfinite(x[row, col])):
                continue
            gy, gx = int(np.floor(float(y[row, col]) + 0.5)), int(np.floor(float(x[row, col]) + 0.5))
            if 0 <= gy < grid_shape[0] and 0 <= gx < grid_shape[1]:
                sums[gy, gx] += image[row, col]
                counts[gy, gx] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts[..., None]


def test_the_mapping_averages_camera_pixels_as_format_md_says():
    rng = np.random.default_rng(7)
    y = rng.uniform(-1.5, 6.5, (23, 31)).astype(np.float32)
    x = rng.uniform(-1.5, 8.5, (23, 31)).astype(np.float32)
    y[3, 4], x[5, 6], y[7, 7] = np.nan, np.nan, np.inf
    y[0, :4] = [0.5, -0.5, 1.4999999, 2.5]  # rounding half up, at the grid's edge too
    image = rng.uniform(0, 1, (23, 31, 3)).astype(np.float32)
    mapping = CameraMapping(y, x, (6, 8))
    expected = brute_force_grid(image, y, x, (6, 8))
    np.testing.assert_allclose(mapping.to_grid(image), expected, rtol=1e-6)
    np.testing.assert_array_equal(mapping.observed, np.isfinite(expected[..., 0]))
    np.testing.assert_allclose(mapping.to_grid(image[..., 1:2])[..., 0], expected[..., 1], rtol=1e-6)  # one channel


def test_the_mapping_is_compact_and_to_grid_copies_no_frame():
    camera, grid = (600, 800), (60, 80)
    rows = np.repeat(np.linspace(-0.4, grid[0] - 0.6, camera[0], dtype=np.float32)[:, None], camera[1], 1)
    cols = np.repeat(np.linspace(-0.4, grid[1] - 0.6, camera[1], dtype=np.float32)[None, :], camera[0], 0)
    mapping = CameraMapping(rows, cols, grid)
    assert mapping.camera_pixels.dtype == mapping.grid_index.dtype == mapping.counts.dtype == np.int32
    stored = mapping.camera_pixels.nbytes + mapping.grid_index.nbytes + mapping.counts.nbytes
    assert stored <= 8 * camera[0] * camera[1] + 4 * grid[0] * grid[1]
    frame = np.ones((*camera, 3), np.float32)
    tracemalloc.start()
    try:
        mapping.to_grid(frame)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # The old to_grid gathered the seen pixels as float64: twice the frame's 5.8 MB.
    assert peak < frame.nbytes / 10, peak
