"""Turning frame files into grid-space radiance: EXR decoding, camera mapping, dark, exposure."""

from __future__ import annotations

import numpy as np

from ..errors import DatasetError
from .exr import check_exr, read_exr_channels, read_exr_rgb
from .manifest import FrameEntry, Manifest

MIN_COVERAGE = 0.01
"""Smallest fraction of a large grid a camera mapping must be able to see (camera pixels over
grid points), checked from the mapping's header before anything of the grid's size is built."""
MIN_COVERAGE_GRID = 2**20
"""Grids up to this many points are exempt from :data:`MIN_COVERAGE` (their memory is small)."""


class CameraMapping:
    """Averages camera pixels onto the grid: grid ``[y, x]`` is the mean of the camera pixels
    whose rounded mapped position is ``[y, x]`` (rounded half up: ``floor(v + 0.5)``).

    Built from ``mapping.exr`` (float channels ``y`` and ``x``, NaN where a pixel sees no grid
    point); positions that round outside the grid are ignored.
    """

    def __init__(self, y: np.ndarray, x: np.ndarray, grid_shape: tuple[int, int]):
        height, width = grid_shape
        self.camera_shape = y.shape
        with np.errstate(invalid="ignore"):
            row = np.floor(y.astype(np.float64) + 0.5)
            col = np.floor(x.astype(np.float64) + 0.5)
            seen = np.isfinite(row) & np.isfinite(col) & (row >= 0) & (row < height) & (col >= 0) & (col < width)
        self.camera_pixels = np.flatnonzero(seen.ravel())
        self.grid_index = (row.ravel()[self.camera_pixels] * width + col.ravel()[self.camera_pixels]).astype(np.int64)
        counts = np.bincount(self.grid_index, minlength=height * width)
        self.observed = (counts > 0).reshape(grid_shape)
        self._inverse_counts = np.where(counts > 0, 1.0 / np.maximum(counts, 1), np.nan)
        self.grid_shape = grid_shape

    def to_grid(self, image: np.ndarray) -> np.ndarray:
        """(Hc, Wc, 3) camera image -> (H, W, 3) float32 grid image, NaN at unobserved points."""
        size = self.grid_shape[0] * self.grid_shape[1]
        flat = image.reshape(-1, 3)[self.camera_pixels].astype(np.float64)
        grid = np.stack(
            [np.bincount(self.grid_index, weights=flat[:, c], minlength=size) for c in range(3)],
            axis=-1,
        )
        grid *= self._inverse_counts[:, None]
        return grid.reshape(*self.grid_shape, 3).astype(np.float32)


class FrameReader:
    """Reads a dataset's frames as grid-space linear radiance (H, W, 3) float32.

    radiance = frame / exposure - dark: the dark frame is in exposure-1 units (FORMAT.md).
    Frames of ``frame_space`` "camera" are averaged onto the grid through the mapping. Files
    resolving outside the dataset folder are refused unless ``allow_outside``. Every file's header
    is checked against the size it must have before its pixels are decoded.
    """

    def __init__(self, manifest: Manifest, allow_outside: bool = False):
        self.manifest = manifest
        self.allow_outside = allow_outside
        self.grid_shape = (manifest.height, manifest.width)
        self.mapping: CameraMapping | None = None
        self.frame_shape, self.size_of = self.grid_shape, "the grid"
        if manifest.frame_space == "camera":
            mapping_path = manifest.file_path(manifest.mapping, allow_outside)
            header = check_exr(mapping_path, ("y", "x"), what="mapping")
            self.frame_shape, self.size_of = (header.height, header.width), "the mapping"
            grid_points = manifest.height * manifest.width
            if grid_points > MIN_COVERAGE_GRID and header.height * header.width < MIN_COVERAGE * grid_points:
                # Every grid point costs response memory, seen or not: a camera of a few pixels
                # under a huge grid would build gigabytes of zeros.
                raise DatasetError(
                    f"{mapping_path}: a camera of {header.height} x {header.width} pixels cannot see "
                    f"{MIN_COVERAGE:.0%} of the {manifest.height} x {manifest.width} grid; "
                    "the grid should be the projector region the camera sees")
            # The mapping's size is only known from its own header: the first frame's header must
            # agree before the mapping is decoded, so a small file cannot claim a huge camera.
            check_exr(manifest.file_path(manifest.frames[0].file, allow_outside), ("R", "G", "B"),
                      self.frame_shape, "frame", self.size_of)
            yx = read_exr_channels(mapping_path, ("y", "x"), self.frame_shape, "mapping")
            self.mapping = CameraMapping(yx[..., 0], yx[..., 1], self.grid_shape)
            if not self.mapping.observed.any():
                raise DatasetError(f"{mapping_path}: no camera pixel maps into the "
                                   f"{manifest.height} x {manifest.width} grid (all NaN or outside)")
        self.dark: np.ndarray | None = None
        if manifest.dark is not None:
            dark_path = manifest.file_path(manifest.dark, allow_outside)
            dark = read_exr_rgb(dark_path, self.frame_shape, "dark frame", self.size_of)
            bad = ~np.isfinite(dark)
            if bad.any():
                raise DatasetError(f"{dark_path}: {int(bad.sum())} NaN or Inf values in the dark frame")
            self.dark = self._to_grid(dark)

    @property
    def observed(self) -> np.ndarray:
        """(H, W) bool: grid points that frames show (all of them in grid frame space)."""
        if self.mapping is None:
            return np.ones(self.grid_shape, bool)
        return self.mapping.observed

    def _to_grid(self, image: np.ndarray) -> np.ndarray:
        return image if self.mapping is None else self.mapping.to_grid(image)

    def read(self, frame: FrameEntry) -> tuple[np.ndarray, int]:
        """Return ``(radiance, bad)``: the frame's (H, W, 3) float32 grid radiance and how many of
        its pixel values were NaN or Inf (the caller decides how to report them).

        Raises DatasetError when scaling by the exposure or subtracting the dark frame takes a
        finite value out of float32's range (to Inf, or a non-zero value to 0).
        """
        path = self.manifest.file_path(frame.file, self.allow_outside)
        image = read_exr_rgb(path, self.frame_shape, "frame", self.size_of)
        bad = int(np.count_nonzero(~np.isfinite(image)))
        grid = self._to_grid(image)
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            scaled = grid / np.float32(frame.exposure)
            radiance = scaled if self.dark is None else scaled - self.dark
        finite = np.isfinite(grid)
        if (~np.isfinite(scaled) & finite).any() or ((scaled == 0) & (grid != 0) & finite).any():
            raise DatasetError(f"{path}: dividing by the exposure {frame.exposure:g} "
                               "takes values out of float32's range")
        if (~np.isfinite(radiance) & finite).any():
            raise DatasetError(f"{path}: subtracting the dark frame takes values out of float32's range")
        return radiance.astype(np.float32, copy=False), bad
