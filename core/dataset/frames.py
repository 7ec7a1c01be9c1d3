"""Turning frame files into grid-space radiance: EXR decoding, camera mapping, dark, exposure.

Frames are read with the manifest's ``channels`` (three for R, G, B; one for a monochrome
camera, whose value every tool takes as R = G = B), from its ``part``, checked against its
``colorspace`` (docs/format/dataset.md, "Frame files").
"""

from __future__ import annotations

from pathlib import Path

import numba
import numpy as np

from ..errors import DatasetError
from .cache import file_identity
from .exr import check_exr, read_exr_channels, visit_exr
from .exr_seen import HeaderCache, PassedHeader
from .exr_header import ExrHeader, frame_channels
from .file_paths import FileResolver
from .manifest import FrameEntry, Manifest

MIN_COVERAGE = 0.01
"""Smallest fraction of a large grid a camera mapping must be able to see (camera pixels over
grid points), checked from the mapping's header before anything of the grid's size is built."""
MIN_COVERAGE_GRID = 2**20
"""Grids up to this many points are exempt from :data:`MIN_COVERAGE` (their memory is small)."""


def dataset_channels(manifest: Manifest, allow_outside: bool = False) -> tuple[str, ...]:
    """The channels a dataset's frames are read with: the manifest's ``channels``, else R, G, B,
    or Y when the first frame holds a single Y and no R, G, B (from its header alone)."""
    if manifest.channels is not None:
        return manifest.channels
    return frame_channels(manifest.file_path(manifest.frames[0].file, allow_outside), manifest.part)


@numba.njit(cache=True, nogil=True)
def _map_camera_pixels(y, x, height, width):  # pragma: no cover - compiled
    """(N,) float32 mapped positions -> (camera pixel, grid point) int32 pairs of the seen ones."""
    grid_of = np.empty(y.size, np.int32)
    seen = 0
    for i in range(y.size):
        # floor(v + 0.5) in float64, as docs/format/dataset.md's rounding; NaN fails every comparison.
        row = np.floor(np.float64(y[i]) + 0.5)
        col = np.floor(np.float64(x[i]) + 0.5)
        if row >= 0 and row < height and col >= 0 and col < width:
            grid_of[i] = np.int32(row) * width + np.int32(col)
            seen += 1
        else:
            grid_of[i] = -1
    pixels = np.empty(seen, np.int32)
    grid = np.empty(seen, np.int32)
    at = 0
    for i in range(y.size):
        if grid_of[i] >= 0:
            pixels[at] = i
            grid[at] = grid_of[i]
            at += 1
    return pixels, grid


@numba.njit(cache=True, nogil=True)
def _camera_mean(flat, pixels, grid_index, counts, out):  # pragma: no cover - compiled
    """out[g] = mean of flat[pixels[i]] over i with grid_index[i] = g; NaN where counts[g] = 0.

    Sums in float64 in camera-pixel order (the order of ``np.bincount``)."""
    total = np.zeros((out.shape[0], flat.shape[1]), np.float64)
    for i in range(pixels.size):
        g = grid_index[i]
        for c in range(flat.shape[1]):
            total[g, c] += flat[pixels[i], c]
    for g in range(out.shape[0]):
        for c in range(flat.shape[1]):
            out[g, c] = total[g, c] / counts[g] if counts[g] > 0 else np.nan


@numba.njit(cache=True, nogil=True)
def _radiance(grid, exposure, dark, has_dark, out):  # pragma: no cover - compiled
    """``out = grid / exposure - dark``: (rows, W, 3) float32 from a C-contiguous (rows, W, C) grid
    and, with ``has_dark``, a dark frame of its shape (R = G = B from a single channel).

    Returns ``(bad, problem)``: how many values of ``grid`` are NaN or Inf, and 1 when dividing
    takes a finite value out of float32's range (to Inf, or a non-zero value to 0), 2 when
    subtracting the dark frame does (to Inf), else 0."""
    rows, width, channels = grid.shape
    flat = out.reshape(out.size) if channels == 3 else np.empty(grid.size, np.float32)
    bad, problem = _scaled(grid.reshape(grid.size), exposure, dark.reshape(dark.size), has_dark, flat)
    if channels != 3:
        for y in range(rows):
            for x in range(width):
                out[y, x, :] = flat[y * width + x]
    return bad, problem


@numba.njit(cache=True, nogil=True)
def _scaled(values, exposure, dark, has_dark, out):  # pragma: no cover - compiled
    """``out[i] = values[i] / exposure - dark[i]`` (no ``dark`` without ``has_dark``) over flat
    float32 arrays; returns ``(bad, problem)`` as :func:`_radiance`. NaN and Inf pass through (a
    positive exposure and a finite dark keep them). The loop has no branch, so the compiler
    vectorises it: 0.05-0.08 ms for a 256 x 256 frame, where a branch per value took 0.3-0.45 ms."""
    bad = 0
    divide = False
    subtract = False
    for i in range(values.size):
        value = values[i]
        scaled = value / exposure
        result = scaled - dark[i] if has_dark else scaled
        finite = np.isfinite(value)
        bad += not finite
        divide |= finite & ((not np.isfinite(scaled)) | ((scaled == 0) & (value != 0)))
        subtract |= np.isfinite(scaled) & (not np.isfinite(result))
        out[i] = result
    return bad, 1 if divide else (2 if subtract else 0)


class CameraMapping:
    """Averages camera pixels onto the grid: grid ``[y, x]`` is the mean of the camera pixels
    whose rounded mapped position is ``[y, x]`` (rounded half up: ``floor(v + 0.5)``).

    Built from ``mapping.exr`` (float channels ``y`` and ``x``, NaN where a pixel sees no grid
    point); positions that round outside the grid are ignored. Stored compactly: two int32 per
    seen camera pixel and one int32 count per grid point (8 bytes a camera pixel for a 20 MP
    camera: 160 MB at most).
    """

    def __init__(self, y: np.ndarray, x: np.ndarray, grid_shape: tuple[int, int]):
        height, width = grid_shape
        self.camera_shape = y.shape
        self.camera_pixels, self.grid_index = _map_camera_pixels(
            np.ascontiguousarray(y, np.float32).ravel(), np.ascontiguousarray(x, np.float32).ravel(),
            height, width)
        self.counts = np.bincount(self.grid_index, minlength=height * width).astype(np.int32)
        self.observed = (self.counts > 0).reshape(grid_shape)
        self.grid_shape = grid_shape

    def to_grid(self, image: np.ndarray) -> np.ndarray:
        """(Hc, Wc, C) camera image -> (H, W, C) float32 grid image, NaN at unobserved points.

        Memory: the (H * W, C) float64 sums and the float32 result; no copy of the image."""
        channels = image.shape[-1]
        grid = np.empty((self.grid_shape[0] * self.grid_shape[1], channels), np.float32)
        _camera_mean(np.ascontiguousarray(image, np.float32).reshape(-1, channels), self.camera_pixels,
                     self.grid_index, self.counts, grid)
        return grid.reshape(*self.grid_shape, channels)


class FrameReader:
    """Reads a dataset's frames as grid-space linear radiance (H, W, 3) float32.

    radiance = frame / exposure - dark: the dark frame is in exposure-1 units (docs/format/dataset.md).
    Frames of ``frame_space`` "camera" are averaged onto the grid through the mapping. Files
    resolving outside the dataset folder are refused unless ``allow_outside``. Every file's header
    is checked against the size it must have before its pixels are decoded.
    """

    def __init__(self, manifest: Manifest, allow_outside: bool = False, channels: tuple[str, ...] | None = None):
        self.manifest = manifest
        self.allow_outside = allow_outside
        self.resolver = FileResolver(manifest.folder, allow_outside)  # each folder resolved once
        self.file_path = self.resolver.locate
        self.headers = HeaderCache()  # the library reads a header shared by all frames once
        self.grid_shape = (manifest.height, manifest.width)
        self.mapping: CameraMapping | None = None
        self.frame_shape, self.size_of = self.grid_shape, "the grid"
        # The caller's when it knows them: the first frame's header is not read again for them.
        self.channels = channels or dataset_channels(manifest, allow_outside)
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
            check_exr(manifest.file_path(manifest.frames[0].file, allow_outside), self.channels,
                      self.frame_shape, "frame", self.size_of, manifest.part, manifest.colorspace)
            yx = read_exr_channels(mapping_path, ("y", "x"), self.frame_shape, "mapping")
            self.mapping = CameraMapping(yx[..., 0], yx[..., 1], self.grid_shape)
            if not self.mapping.observed.any():
                raise DatasetError(f"{mapping_path}: no camera pixel maps into the "
                                   f"{manifest.height} x {manifest.width} grid (all NaN or outside)")
        self.dark: np.ndarray | None = None
        if manifest.dark is not None:
            dark_path = manifest.file_path(manifest.dark, allow_outside)
            dark = self._read_file(dark_path, "dark frame")
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

    @property
    def monochrome(self) -> bool:
        """True when frames are read from one channel (a monochrome camera)."""
        return len(self.channels) == 1

    def _read_file(self, path, what: str, rows: tuple[int, int] | None = None,
                   descriptor: int | None = None) -> np.ndarray:
        """(Hf, Wf, len(channels)) float32 pixels of a frame or the dark frame (``rows``: only
        those rows of a grid-space file; ``descriptor``: the file already open)."""
        return read_exr_channels(path, self.channels, self.frame_shape, what, self.size_of,
                                 self.manifest.part, self.manifest.colorspace, rows, self.headers, descriptor)

    def _to_grid(self, image: np.ndarray) -> np.ndarray:
        return image if self.mapping is None else self.mapping.to_grid(image)

    def check(self, frame: FrameEntry) -> tuple[ExrHeader, PassedHeader | None]:
        """Check a frame's header (size, channels, part, colourspace) without decoding it; returns
        it and its entry in :attr:`headers` (the header that frames sharing its bytes have)."""
        header, _, passed = visit_exr(self.file_path(frame.file), self.channels, self.frame_shape, "frame",
                                      self.size_of, self.manifest.part, self.manifest.colorspace, self.headers)
        return header, passed

    def read(self, frame: FrameEntry, rows: tuple[int, int] | None = None,
             out: np.ndarray | None = None, identity: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Return ``(radiance, bad)``: the frame's (H, W, 3) float32 grid radiance (R = G = B for a
        monochrome camera), written into ``out`` when given, and how many of its pixel values were
        NaN or Inf (the caller decides how to report them). With ``rows`` = ``(first, stop)``, only
        those grid rows (a grid-space frame decodes only them; a camera frame is decoded whole and
        mapped, then cut). ``identity``: a (4,) int64 row that receives the file's identity
        (:func:`.cache.file_identity` of the file read).

        Raises DatasetError when scaling by the exposure or subtracting the dark frame takes a
        finite value out of float32's range (to Inf, or a non-zero value to 0).
        """
        descriptor, path, status = self.resolver.open(frame.file)  # located, opened and checked in one visit
        if identity is not None:
            identity[:] = file_identity(status)
        first, stop = rows if rows is not None else (0, self.grid_shape[0])
        image = self._read_file(path, "frame", rows if self.mapping is None else None, descriptor)
        camera_bad = 0
        if self.mapping is not None:  # decoded whole for every band: its bad values count with the first
            camera_bad = int(np.count_nonzero(~np.isfinite(image))) if first == 0 else 0
            grid = self._to_grid(image)[first:stop]
        else:
            grid = image
        dark = self.dark[first:stop] if self.dark is not None else np.zeros((0, 0, grid.shape[2]), np.float32)
        radiance = out if out is not None else np.empty((*grid.shape[:2], 3), np.float32)
        bad, problem = _radiance(grid, np.float32(frame.exposure), dark, self.dark is not None, radiance)
        if problem:
            raise self.scaling_error(frame, problem)
        return radiance, camera_bad if self.mapping is not None else int(bad)

    def scaling_error(self, frame: FrameEntry, problem: int) -> DatasetError:
        """The error of a frame whose scaling took values out of float32's range: ``problem`` as
        :func:`_radiance` returns it (1: dividing by the exposure, 2: subtracting the dark frame)."""
        path = Path(self.resolver.folder, frame.file)
        if problem == 1:
            return DatasetError(f"{path}: dividing by the exposure {frame.exposure:g} "
                                "takes values out of float32's range")
        return DatasetError(f"{path}: subtracting the dark frame takes values out of float32's range")
