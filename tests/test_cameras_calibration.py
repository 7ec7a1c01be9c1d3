"""Dark frame and colour calibration against the simulated rig's known read noise and camera matrix."""

import math

import numpy as np
import pytest
from ringlight.core.capture.calibration import (
    CalibrationError,
    calibrate_colour,
    capture_white,
    colorchecker_xyz,
    fit_camera_matrix,
    measure_dark,
)
from ringlight.core.capture.simulated_rig import CAMERA_RGB_TO_XYZ, SimulatedRig, colorchecker_windows


def test_dark_frame_noise_equals_the_simulated_read_noise():
    rig = SimulatedRig(np.zeros((10, 10, 3, 3, 3), np.float32))
    dark = measure_dark(rig.camera, rig.projector, 0.01, count=16)
    # No light: Gaussian read noise (sigma 2) rounded to integers adds the uniform 1/12 variance.
    expected = math.sqrt(rig.sensor.read_noise**2 + 1 / 12)
    samples = dark.mean.size * (dark.frames - 1)
    standard_error = expected / math.sqrt(2 * samples)  # of a standard deviation from n samples
    assert abs(dark.noise - expected) < 3 * standard_error
    assert abs(dark.offset) < 3 * expected / math.sqrt(dark.mean.size * dark.frames)
    assert dark.mean.shape == (*rig.camera.frame_shape[:2], 3)
    with pytest.raises(CalibrationError, match="at least 2 frames"):
        measure_dark(rig.camera, rig.projector, 0.01, count=1)


def test_fitted_matrix_maps_known_patch_rgbs_to_their_xyz():
    xyz = colorchecker_xyz()
    matrix = np.array([[0.6, 0.3, 0.1], [0.25, 0.7, 0.05], [0.02, 0.1, 0.9]])
    rgb = np.linalg.solve(matrix, xyz.T).T
    fit = fit_camera_matrix(rgb * 1000.0)  # counts per second: the matrix absorbs the scale
    np.testing.assert_allclose(fit.matrix * 1000.0, matrix, atol=1e-12)
    np.testing.assert_allclose(rgb * 1000.0 @ fit.matrix.T, xyz, atol=1e-12)
    assert fit.residual < 1e-12
    # The manifest's matrix is scaled so that camera white, RGB (1, 1, 1), has Y = 1.
    np.testing.assert_allclose(fit.colorspace()["matrix"], matrix / matrix[1].sum(), atol=1e-12)
    with pytest.raises(CalibrationError, match="do not span three dimensions"):
        fit_camera_matrix(np.repeat(rgb[:, :1], 3, axis=1))


def camera_pixel(sampling, y, x):
    """Inverse of CameraSampling.projector_position: the camera (row, col) seeing projector (y, x)."""
    angle = math.radians(sampling.rotation_deg)
    dy, dx = y - sampling.offset[0], x - sampling.offset[1]
    v = math.cos(angle) * dy - math.sin(angle) * dx
    u = math.sin(angle) * dy + math.cos(angle) * dx
    return v * sampling.scale + sampling.margin - 0.5, u * sampling.scale + sampling.margin - 0.5


def test_the_colour_step_recovers_the_simulated_cameras_matrix():
    height, width = 28, 42
    rig = SimulatedRig(colorchecker_windows(height, width))
    white = capture_white(rig.camera, rig.projector)
    # Centres of patches 1, 6, 19, 24 on the grid, seen through the rig's camera sampling.
    corners = [camera_pixel(rig.sampling, (row + 0.5) * height / 4, (col + 0.5) * width / 6)
               for row, col in ((0, 0), (0, 5), (3, 0), (3, 5))]
    fit = calibrate_colour(white, corners, half_size=2)
    # Frames are counts per second = sensor gain x camera RGB, so the fit is the camera's matrix / gain.
    # Measured: largest difference 0.004 (shot noise of 25 pixels per patch).
    np.testing.assert_allclose(fit.matrix * rig.sensor.gain, CAMERA_RGB_TO_XYZ, atol=0.01)
    assert fit.residual < 0.005
