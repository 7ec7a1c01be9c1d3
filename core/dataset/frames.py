"""Turning frame files into grid-space radiance: EXR decoding, camera mapping, dark, exposure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .exr import exr_size, read_exr_channels, read_exr_rgb
from .manifest import FrameEntry, Manifest


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
    resolving outside the dataset folder are refused unless ``allow_outside``.
    """

    def __init__(self, manifest: Manifest, allow_outside: bool = False):
        self.manifest = manifest
        self.allow_outside = allow_outside
        self.grid_shape = (manifest.height, manifest.width)
        self.mapping: CameraMapping | None = None
        if manifest.frame_space == "camera":
            mapping_path = manifest.file_path(manifest.mapping, allow_outside)
            yx = read_exr_channels(mapping_path, ("y", "x"))
            self.mapping = CameraMapping(yx[..., 0], yx[..., 1], self.grid_shape)
            if not self.mapping.observed.any():
                raise DatasetError(f"{mapping_path}: no camera pixel maps into the "
                                   f"{manifest.height} x {manifest.width} grid (all NaN or outside)")
            self.frame_shape = self.mapping.camera_shape
        else:
            self.frame_shape = self.grid_shape
        self.dark: np.ndarray | None = None
        if manifest.dark is not None:
            dark_path = manifest.file_path(manifest.dark, allow_outside)
            dark = self._read_sized(dark_path, "dark frame")
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

    def _read_sized(self, path: Path, what: str) -> np.ndarray:
        height, width = exr_size(path)  # the header, before anything is decoded
        if (height, width) != tuple(self.frame_shape):
            expected = "the mapping" if self.mapping is not None else "the grid"
            raise DatasetError(
                f"{path}: {what} is {height} x {width}, expected "
                f"{self.frame_shape[0]} x {self.frame_shape[1]} (the size of {expected})"
            )
        return read_exr_rgb(path, (height, width))

    def _to_grid(self, image: np.ndarray) -> np.ndarray:
        return image if self.mapping is None else self.mapping.to_grid(image)

    def read(self, frame: FrameEntry) -> tuple[np.ndarray, int]:
        """Return ``(radiance, bad)``: the frame's (H, W, 3) float32 grid radiance and how many of
        its pixel values were NaN or Inf (the caller decides how to report them)."""
        image = self._read_sized(self.manifest.file_path(frame.file, self.allow_outside), "frame")
        bad = int(np.count_nonzero(~np.isfinite(image)))
        grid = self._to_grid(image)
        with np.errstate(over="ignore", under="ignore"):
            radiance = grid / np.float32(frame.exposure)
        finite = np.isfinite(grid)
        if (~np.isfinite(radiance) & finite).any() or ((radiance == 0) & (grid != 0) & finite).any():
            raise DatasetError(f"{self.manifest.folder / frame.file}: dividing by the exposure {frame.exposure:g} "
                               "takes values out of float32's range")
        if self.dark is not None:
            radiance -= self.dark
        return radiance.astype(np.float32, copy=False), bad
