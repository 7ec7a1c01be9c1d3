"""Projector-camera correspondence from Gray code patterns (OpenCV ``structured_light``).

Each camera pixel decodes the projector pixel it sees from the Gray code captures (OpenCV's
``GrayCodePattern.getProjPixel``), where the white and black captures show light (a shadow mask
keeps the rest out). The decoded integer positions are then fitted by a homography (OpenCV,
least median of squares: a flat surface seen through a lens without distortion; decoding errors
at stripe edges, which subsurface scattering blurs, are outvoted), which gives every camera pixel a
sub-pixel projector position. (RANSAC with a sub-pixel threshold fits worse here: integer decoding
alone scatters points by up to 0.71 px.) The mapping stored in a dataset (``mapping`` of
docs/format/dataset.md) is that position minus half a pixel, so that rounding it gives the
projector pixel the camera pixel's centre lies in.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import RinglightError
from .hardware import Camera, Projector

INLIER_PX = 1.0
"""Decoded pixels within this distance of the fit count as inliers (integer decoding alone is off
by up to 0.71 px)."""
MIN_SHADOW_CONTRAST = 0.1
"""A camera pixel is lit when white - black exceeds this fraction of the brightest difference."""


class CorrespondenceError(RinglightError):
    """The patterns could not be decoded into a usable correspondence."""


@dataclass(frozen=True, eq=False)
class Correspondence:
    """Camera -> projector correspondence.

    Attributes
    ----------
    homography
        (3, 3) from camera pixel-centre coordinates (x, y) to projector coordinates (x, y).
    lit
        (rows, cols) bool: camera pixels the projector lights (shadow mask).
    decoded
        (rows, cols, 2) float64 decoded projector pixel (y, x) per camera pixel; NaN undecoded.
    inliers, residual_rms
        Decoded pixels the homography explains (within INLIER_PX) and their RMS
        residual in projector pixels (decoded pixel centres against the fit).
    white
        (rows, cols) float64 grey camera view under the all-white pattern, black capture
        subtracted.
    """

    homography: np.ndarray
    lit: np.ndarray
    decoded: np.ndarray
    inliers: int
    residual_rms: float
    white: np.ndarray

    def projector_view(self, projector_size: tuple[int, int]) -> np.ndarray:
        """(H, W) float64: the white view resampled to projector pixels (mean of the camera pixels
        that see each one; NaN where none does). Where to draw a region of interest."""
        mapping = self.mapping((0, 0, *projector_size))
        seen = np.isfinite(mapping[..., 0])
        y = np.floor(mapping[seen, 0] + 0.5).astype(np.int64)
        x = np.floor(mapping[seen, 1] + 0.5).astype(np.int64)
        total = np.zeros(projector_size)
        count = np.zeros(projector_size)
        np.add.at(total, (y, x), self.white[seen])
        np.add.at(count, (y, x), 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, total / count, np.nan)

    def projector_position(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projector (y, x) of camera pixel centres (rows, cols), by the fitted homography."""
        points = np.stack([np.asarray(cols, np.float64) + 0.5, np.asarray(rows, np.float64) + 0.5], -1)
        mapped = cv2.perspectiveTransform(points.reshape(-1, 1, 2), self.homography).reshape(points.shape)
        return mapped[..., 1], mapped[..., 0]

    def mapping(self, roi: tuple[int, int, int, int]) -> np.ndarray:
        """(rows, cols, 2) float32 grid position (y, x) each camera pixel sees, for the grid of
        projector pixels ``roi = (y0, x0, y1, x1)`` (end exclusive); NaN where unlit or outside."""
        rows, cols = np.mgrid[:self.lit.shape[0], :self.lit.shape[1]]
        y, x = self.projector_position(rows, cols)
        y0, x0, y1, x1 = roi
        grid_y, grid_x = y - y0 - 0.5, x - x0 - 0.5
        inside = self.lit & (np.floor(y) >= y0) & (np.floor(y) < y1) & (np.floor(x) >= x0) & (np.floor(x) < x1)
        mapping = np.full((*self.lit.shape, 2), np.nan, np.float32)
        mapping[inside, 0] = grid_y[inside]
        mapping[inside, 1] = grid_x[inside]
        return mapping


def gray_code_patterns(projector_size: tuple[int, int]) -> list[np.ndarray]:
    """OpenCV's Gray code patterns (and inverses) for a projector of (height, width), as float32
    images in [0, 1]."""
    height, width = projector_size
    generator = cv2.structured_light.GrayCodePattern.create(width, height)
    ok, patterns = generator.generate()
    if not ok:
        raise CorrespondenceError(f"OpenCV could not make Gray code patterns for {width} x {height}")
    return [np.asarray(pattern, np.float32) / 255.0 for pattern in patterns]


def capture_gray_code(camera: Camera, projector: Projector, exposure: float,
                      progress: Callable[[float], None] | None = None) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Show every Gray code pattern and capture it: ``(captures, black, white)`` raw frames."""
    patterns = gray_code_patterns(projector.size)
    captures = []
    steps = len(patterns) + 2
    for index, pattern in enumerate(patterns):
        captures.append(_shot(camera, projector, exposure, lambda pattern=pattern: projector.show(pattern)))
        if progress is not None:
            progress((index + 1) / steps)
    black = _shot(camera, projector, exposure, projector.show_black)
    white = _shot(camera, projector, exposure, projector.show_white)
    if progress is not None:
        progress(1.0)
    return captures, black, white


def decode_gray_code(captures, black, white, projector_size: tuple[int, int]) -> Correspondence:
    """Decode captures (raw frames, in pattern order) into a :class:`Correspondence`."""
    grey = [_grey(frame) for frame in captures]
    black_grey, white_grey = _grey(black), _grey(white)
    contrast = white_grey - black_grey
    if not np.isfinite(contrast).all() or contrast.max() <= 0:
        raise CorrespondenceError("the white pattern is no brighter than the black one: is the projector on and seen?")
    lit = contrast > MIN_SHADOW_CONTRAST * contrast.max()
    scale = 255.0 / max(float(white_grey.max()), 1e-12)
    images = [np.clip(np.round(image * scale), 0, 255).astype(np.uint8) for image in grey]
    height, width = projector_size
    decoder = cv2.structured_light.GrayCodePattern.create(width, height)
    decoder.setWhiteThreshold(1)
    decoded = np.full((*lit.shape, 2), np.nan)
    for row, col in zip(*np.nonzero(lit)):
        error, (px, py) = decoder.getProjPixel(images, int(col), int(row))
        if not error and 0 <= px < width and 0 <= py < height:
            decoded[row, col] = (py, px)
    good = np.isfinite(decoded[..., 0])
    if good.sum() < 8:
        raise CorrespondenceError(f"only {int(good.sum())} camera pixels decoded a projector pixel; "
                                  "check focus, exposure and that the projector fills the view")
    rows, cols = np.nonzero(good)
    camera_points = np.stack([cols + 0.5, rows + 0.5], -1).astype(np.float64)
    projector_points = np.stack([decoded[rows, cols, 1] + 0.5, decoded[rows, cols, 0] + 0.5], -1)
    homography, _ = cv2.findHomography(camera_points, projector_points, cv2.LMEDS)
    if homography is None:
        raise CorrespondenceError("no homography fits the decoded correspondence")
    fitted = cv2.perspectiveTransform(camera_points.reshape(-1, 1, 2), homography).reshape(-1, 2)
    distance = np.sqrt(((fitted - projector_points) ** 2).sum(1))
    inliers = distance <= INLIER_PX
    residual = float(np.sqrt((distance[inliers] ** 2).mean()))
    return Correspondence(homography, lit, decoded, int(inliers.sum()), residual, contrast)


def _shot(camera: Camera, projector: Projector, exposure: float, show) -> np.ndarray:
    show()
    if projector.settle_time > 0:
        time.sleep(projector.settle_time)
    return np.asarray(camera.capture(exposure), np.float32)


def _grey(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame, np.float64)
    return frame.mean(axis=-1) if frame.ndim == 3 else frame
