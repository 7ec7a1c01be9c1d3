"""Calibrations a rig needs before a scan: the dark frame and the camera's colour matrix.

- Dark frame: the projector shows black, N frames are averaged; the temporal noise (each pixel's
  standard deviation over the frames, root-mean-square over pixels) is the camera's read noise
  (plus dark-current shot noise at long exposures), in raw counts.
- Colour: a ColorChecker (24 patches, 4 rows x 6 columns, dark skin top left) photographed under
  the projector's white. The patch centres come from the four corner patches' centres (a manual
  picker: colour-checker-detection would need the non-headless ``opencv-python``, which cannot be
  installed beside ringlight's ``opencv-contrib-python-headless``); the mean camera RGB of each
  patch is fitted by least squares to the patches' published CIE XYZ (colour-science's
  "ColorChecker24 - After November 2014", illuminant D50), giving the 3 x 3 matrix that the
  manifest's ``colorspace: {"matrix": M}`` records (docs/format/dataset.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..colourspaces import colour_module
from ..errors import RinglightError
from .hardware import Camera, Projector
from .hdr import MergedFrame, merge_brackets
from .scan import as_rgb, capture_with_timeout
from .workflow import white_exposure

CHECKER_ROWS, CHECKER_COLUMNS = 4, 6
CHECKER_NAME = "ColorChecker24 - After November 2014"


class CalibrationError(RinglightError):
    """A calibration could not be made (no usable patches, a singular fit)."""


@dataclass(frozen=True, eq=False)
class DarkFrame:
    """An averaged dark frame.

    Attributes
    ----------
    mean
        (rows, cols, 3) float32 raw counts with the projector black (black level included).
    noise
        Temporal noise in raw counts: sqrt(mean over pixels of each pixel's variance over frames).
    frames, exposure
        How many frames were averaged, each exposed ``exposure`` seconds.
    black_level
        The camera's own black level (raw counts).
    """

    mean: np.ndarray
    noise: float
    frames: int
    exposure: float
    black_level: float

    @property
    def offset(self) -> float:
        """Mean dark signal above the camera's black level, raw counts."""
        return float(self.mean.mean() - self.black_level)


def measure_dark(camera: Camera, projector: Projector, exposure: float, count: int = 8,
                 progress: Callable[[float], None] | None = None) -> DarkFrame:
    """Average ``count`` (>= 2) frames at ``exposure`` seconds with the projector black."""
    if count < 2:
        raise CalibrationError(f"a dark frame needs at least 2 frames to measure noise, got {count}")
    projector.show_black()
    total = total_squares = None
    for index in range(count):
        frame = as_rgb(capture_with_timeout(camera, exposure)).astype(np.float64)
        total = frame if total is None else total + frame
        total_squares = frame**2 if total_squares is None else total_squares + frame**2
        if progress is not None:
            progress((index + 1) / count)
    mean = total / count
    variance = np.maximum(total_squares - count * mean**2, 0.0) / (count - 1)
    return DarkFrame(mean.astype(np.float32), float(np.sqrt(variance.mean())), count, exposure, camera.black_level)


def colorchecker_xyz() -> np.ndarray:
    """(24, 3) CIE XYZ (Y of a perfect white = 1) of the ColorChecker patches in reading order.

    >>> round(float(colorchecker_xyz()[18, 1]), 2)  # patch 19, white 9.5
    0.88
    """
    colour = colour_module()
    checker = colour.CCS_COLOURCHECKERS[CHECKER_NAME]
    return colour.xyY_to_XYZ(np.array(list(checker.data.values()), np.float64))


def patch_centres(corners) -> np.ndarray:
    """(24, 2) [y, x] centres of the patches from the centres of the corner patches.

    ``corners``: (4, 2) [y, x] of patch 1 (dark skin, top left), 6 (bluish green, top right),
    19 (white, bottom left) and 24 (black, bottom right), in image pixels. The chart is taken
    as a flat grid seen in perspective, interpolated bilinearly between the corners.
    """
    top_left, top_right, bottom_left, bottom_right = np.asarray(corners, np.float64)
    v = np.arange(CHECKER_ROWS)[:, None, None] / (CHECKER_ROWS - 1)
    u = np.arange(CHECKER_COLUMNS)[None, :, None] / (CHECKER_COLUMNS - 1)
    centres = ((1 - v) * ((1 - u) * top_left + u * top_right) + v * ((1 - u) * bottom_left + u * bottom_right))
    return centres.reshape(-1, 2)


def sample_patches(image: np.ndarray, centres: np.ndarray, half_size: int) -> np.ndarray:
    """(24, 3) mean RGB of the (2 half_size + 1)^2 pixels around each centre of ``image``
    (rows, cols, 3); CalibrationError when a square leaves the image or holds NaN."""
    rows, cols = image.shape[:2]
    means = []
    for number, (y, x) in enumerate(np.round(centres).astype(np.int64), start=1):
        if not (half_size <= y < rows - half_size and half_size <= x < cols - half_size):
            raise CalibrationError(f"patch {number} at [{y}, {x}] is too close to the image's edge")
        square = image[y - half_size:y + half_size + 1, x - half_size:x + half_size + 1].reshape(-1, 3)
        if not np.isfinite(square).all():
            raise CalibrationError(f"patch {number} at [{y}, {x}] holds pixels without a value")
        means.append(square.mean(axis=0))
    return np.array(means)


@dataclass(frozen=True, eq=False)
class ColourFit:
    """A camera-RGB -> CIE XYZ matrix.

    Attributes
    ----------
    matrix
        (3, 3): XYZ = matrix @ rgb, rgb in the frames' units (camera counts per second).
    rgb, xyz
        (24, 3) the patches' measured camera RGB and reference XYZ.
    residual
        RMS of (matrix @ rgb - xyz) over patches and components, in XYZ units (Y of white 1).
    """

    matrix: np.ndarray
    rgb: np.ndarray
    xyz: np.ndarray
    residual: float

    def colorspace(self) -> dict:
        """The manifest's ``colorspace`` value (docs/format/dataset.md): ``{"matrix": [[...], [...], [...]]}``,
        the matrix scaled so that camera RGB (1, 1, 1) has Y = 1. A dataset's values are relative
        radiance (their scale depends on exposure and gain), and the scale keeps the matrix's
        entries near 1 where a reader's checks (singularity, white point) expect them."""
        normalised = self.matrix / self.matrix[1].sum()
        return {"matrix": [[float(value) for value in row] for row in normalised]}


def fit_camera_matrix(rgb, xyz=None) -> ColourFit:
    """Least-squares 3 x 3 matrix taking the patches' camera ``rgb`` (N, 3) to ``xyz`` (N, 3;
    default the ColorChecker's); CalibrationError when the patches do not span three colours."""
    rgb = np.asarray(rgb, np.float64)
    xyz = colorchecker_xyz() if xyz is None else np.asarray(xyz, np.float64)
    if rgb.shape != xyz.shape or rgb.shape[-1] != 3:
        raise CalibrationError(f"need one camera RGB per reference XYZ, got {rgb.shape} and {xyz.shape}")
    singular = np.linalg.svd(rgb, compute_uv=False)
    if not np.isfinite(rgb).all() or singular[-1] <= 1e-6 * singular[0]:
        raise CalibrationError("the patches' camera colours do not span three dimensions "
                               "(a monochrome camera, or the chart not in view)")
    transposed, *_ = np.linalg.lstsq(rgb, xyz, rcond=None)
    matrix = transposed.T
    residual = float(np.sqrt(np.mean((rgb @ matrix.T - xyz) ** 2)))
    return ColourFit(matrix, rgb, xyz, residual)


def capture_white(camera: Camera, projector: Projector) -> MergedFrame:
    """The scene under the projector's white at the exposure that fills about 60 % of the range
    (:func:`.workflow.white_exposure`): counts per second, black level subtracted."""
    exposure = white_exposure(camera, projector)
    projector.show_white()
    frame = as_rgb(capture_with_timeout(camera, exposure))
    projector.show_black()
    return merge_brackets([frame], [exposure], camera.black_level, camera.saturation_level)


def calibrate_colour(white: MergedFrame | np.ndarray, corners, half_size: int = 2) -> ColourFit:
    """The matrix from a (rows, cols, 3) white-lit chart image (a merged frame's radiance, black
    subtracted) and the four corner patches' centres (see :func:`patch_centres`)."""
    image = white.radiance if isinstance(white, MergedFrame) else np.asarray(white)
    return fit_camera_matrix(sample_patches(image, patch_centres(corners), half_size))
