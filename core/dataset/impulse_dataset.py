"""Opening impulse datasets (FORMAT.md v1) into a compact in-memory response model.

The model never forms the dense N x N light transport. For each grid point ``p`` it keeps the
radiance seen at ``p`` from every lit point within ``max_radius`` of it:

    responses[y, x, k, c] = I_q(p)[c]  with  p = [y, x],  q = p + offsets[k],

where ``offsets`` are all integer offsets with ``|d| <= max_radius`` (``disc_offsets``).
Invariant: entries whose ``q`` lies outside the grid or is missing (lit in no frame), and all
entries of unobserved ``p``, hold exactly 0; ``lit_counts`` tells which ``q`` exist. Memory: ``H * W * K * 3 * 4`` bytes with ``K ~ pi * max_radius**2``, e.g.
96 x 96 at max_radius 24 (K = 1789) is 198 MB.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from ..errors import DatasetError
from . import cache
from .frames import FrameReader, dataset_channels
from .manifest import Manifest, read_manifest

ProgressCallback = Callable[[float], None]
"""Called with the fraction of work done in [0, 1]; may raise :class:`Cancelled` to stop."""

MEMORY_LIMIT_BYTES = 8 * 2**30
"""Largest response array :func:`open_dataset` builds unless told otherwise."""


@dataclass(frozen=True, eq=False)
class ImpulseDataset:
    """An opened impulse dataset: manifest plus the response model of the module docstring.

    Attributes
    ----------
    manifest
        The validated manifest.
    max_radius
        Radius (grid steps) up to which responses are kept: the manifest's ``max_radius``, or
        for one-point-per-frame datasets without one, the radius the opener asked for.
    offsets
        (K, 2) int64 offsets ``[dy, dx]`` of the response array's offset axis.
    responses
        (H, W, K, 3) float32 (possibly a read-only memory map of the cache).
    lit_counts
        (H, W) int32: frames in which each point was lit; 0 marks a missing point.
    observed
        (H, W) bool: grid points the frames show (camera datasets may miss some).
    channels
        The frame channels read: three (R, G, B) or one (a monochrome camera, whose responses
        hold its value in all three of R, G, B).
    """

    manifest: Manifest
    max_radius: float
    offsets: np.ndarray
    responses: np.ndarray
    lit_counts: np.ndarray
    observed: np.ndarray
    channels: tuple[str, ...] = ("R", "G", "B")

    @property
    def monochrome(self) -> bool:
        """True for a monochrome camera's dataset (grey: R = G = B everywhere)."""
        return len(self.channels) == 1

    @property
    def path(self) -> Path:
        return self.manifest.folder

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (self.manifest.height, self.manifest.width)

    @property
    def colorspace(self) -> str:
        return self.manifest.colorspace

    @property
    def lit(self) -> np.ndarray:
        """(H, W) bool: points lit in at least one frame."""
        return self.lit_counts > 0

    @functools.cached_property
    def validity(self) -> np.ndarray:
        """(H, W, K) uint8: 1 where ``responses[y, x, k]`` holds a real response (the lit point
        ``q = p + offsets[k]`` is inside the grid and not missing, and ``p`` is observed).

        Computed on first use and kept: 1 byte per entry, 1/12 of the response array.
        """
        validity = np.empty(self.responses.shape[:3], np.uint8)
        _fill_validity(
            np.ascontiguousarray(self.lit_counts > 0), np.ascontiguousarray(self.observed),
            np.ascontiguousarray(self.offsets[:, 0]), np.ascontiguousarray(self.offsets[:, 1]), validity,
        )
        return validity

    @property
    def missing_count(self) -> int:
        """Number of grid points lit in no frame."""
        return int(np.count_nonzero(self.lit_counts == 0))

    def impulse_image(self, y: int, x: int) -> np.ndarray:
        """Impulse image of lit point ``q = [y, x]``: (H, W, 3) float32, NaN beyond max_radius,
        at unobserved points, and everywhere when ``q`` is missing."""
        height, width = self.grid_shape
        image = np.full((height, width, 3), np.nan, np.float32)
        if not self.lit_counts[y, x]:
            return image
        # I_q(p) is stored at p = q - d for offset index k of d.
        py = y - self.offsets[:, 0]
        px = x - self.offsets[:, 1]
        inside = (py >= 0) & (py < height) & (px >= 0) & (px < width)
        k = np.flatnonzero(inside)
        image[py[k], px[k]] = self.responses[py[k], px[k], k]
        image[~self.observed] = np.nan
        return image

    def steady_state(self) -> np.ndarray:
        """Appearance under full illumination of the grid: (H, W, 3) float32, the sum at each
        point of the responses of all lit points within max_radius; NaN where unobserved."""
        total = np.zeros((*self.grid_shape, 3), np.float64)
        for row in range(self.grid_shape[0]):
            total[row] = self.responses[row].sum(axis=1, dtype=np.float64)
        total[~self.observed] = np.nan
        return total.astype(np.float32)


@numba.njit(parallel=True, cache=True, nogil=True)
def _fill_validity(lit, observed, dy, dx, validity):
    height, width = lit.shape
    for y in numba.prange(height):
        for x in range(width):
            for k in range(dy.size):
                qy = y + dy[k]
                qx = x + dx[k]
                inside = 0 <= qy < height and 0 <= qx < width
                validity[y, x, k] = 1 if inside and observed[y, x] and lit[qy, qx] else 0


def disc_offsets(max_radius: float) -> np.ndarray:
    """All integer offsets with ``|d| <= max_radius``, as (K, 2) int64 ``[dy, dx]``.

    Ordered by distance from the centre (then by angle): the layout of the response array's
    offset axis, in which every default ring is one contiguous run of offsets.
    """
    reach = int(np.floor(max_radius))
    dy, dx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    dy, dx = dy.ravel(), dx.ravel()
    inside = dy * dy + dx * dx <= max_radius * max_radius + 1e-9
    dy, dx = dy[inside], dx[inside]
    order = np.lexsort((np.arctan2(dy, dx), dy * dy + dx * dx))
    return np.stack([dy[order], dx[order]], axis=1).astype(np.int64)


def disc_offset_count(max_radius: float) -> int:
    """``len(disc_offsets(max_radius))``, counted row by row without building the offsets."""
    reach = int(np.floor(max_radius))
    rows = np.arange(-reach, reach + 1, dtype=np.float64)
    half_widths = np.minimum(np.floor(np.sqrt(np.maximum(max_radius * max_radius + 1e-9 - rows * rows, 0.0))), reach)
    return int((2 * half_widths + 1).sum())


def response_memory_bytes(grid_shape: tuple[int, int], max_radius: float) -> int:
    """Bytes of the (H, W, K, 3) float32 response array for a grid and max radius (arithmetic
    only: a huge grid or radius is refused before anything of its size is allocated)."""
    return int(grid_shape[0]) * int(grid_shape[1]) * disc_offset_count(max_radius) * 3 * 4


def effective_max_radius(manifest: Manifest, radius: float | None = None) -> float:
    """The max radius a dataset is opened at (see :func:`open_dataset`)."""
    if manifest.max_radius is not None:
        return manifest.max_radius
    if radius is not None:
        return float(radius)
    return math.hypot(manifest.height - 1, manifest.width - 1)


def open_dataset(
    path: str | Path | Manifest,
    *,
    radius: float | None = None,
    use_cache: bool = True,
    progress: ProgressCallback | None = None,
    memory_limit: int = MEMORY_LIMIT_BYTES,
    allow_outside: bool = False,
) -> ImpulseDataset:
    """Open an impulse dataset folder (or its ``dataset.json``).

    Parameters
    ----------
    path
        Dataset folder, its ``dataset.json``, or a :class:`Manifest` already read.
    radius
        For datasets without ``max_radius`` (one lit point per frame): the largest distance in
        grid steps any ring will reach; responses are kept up to it. Default: the grid diagonal.
        Ignored when the manifest sets ``max_radius``.
    use_cache
        Read and write the packed cache (see :mod:`ringlight.core.cache`).
    progress
        Called with the fraction of frames read; may raise :class:`Cancelled`.
    memory_limit
        Refuse to build a response array larger than this many bytes.
    allow_outside
        Read frames, dark and mapping files that resolve (through symbolic links) outside the
        dataset folder; refused by default.

    Raises
    ------
    DatasetError
        For any problem with the manifest or a file, naming the file.
    """
    manifest = path if isinstance(path, Manifest) else read_manifest(path)
    max_radius = effective_max_radius(manifest, radius)
    needed = response_memory_bytes((manifest.height, manifest.width), max_radius)
    if needed > memory_limit:
        raise DatasetError(
            f"{manifest.path}: responses up to radius {max_radius:g} need {needed / 2**30:.1f} GiB "
            f"(limit {memory_limit / 2**30:.1f} GiB); open with a smaller radius"
        )
    offsets = disc_offsets(max_radius)
    channels = dataset_channels(manifest, allow_outside)  # from the first frame's header alone
    location = cache.cache_location(manifest.folder) if use_cache else None
    key = cache.cache_key(manifest, max_radius) if use_cache else ""
    height, width = manifest.height, manifest.width
    expected = {"responses": ((height, width, len(offsets), 3), np.dtype(np.float32)),
                "lit_counts": ((height, width), np.dtype(np.int32)),
                "observed": ((height, width), np.dtype(bool))}
    arrays = cache.load_cache(location, key, expected) if use_cache else None
    if arrays is None:
        arrays = _assemble_responses(manifest, offsets, progress, allow_outside)
        if use_cache:
            cache.save_cache(location, key, arrays)
    elif progress is not None:
        progress(1.0)
    return ImpulseDataset(
        manifest=manifest, max_radius=max_radius, offsets=offsets, responses=arrays.responses,
        lit_counts=arrays.lit_counts, observed=arrays.observed, channels=channels,
    )


def _assemble_responses(
    manifest: Manifest, offsets: np.ndarray, progress: ProgressCallback | None, allow_outside: bool = False
) -> cache.CachedArrays:
    """Read every frame and scatter each lit point's light into the offset layout."""
    height, width = manifest.height, manifest.width
    reader = FrameReader(manifest, allow_outside)
    # The first frame is read before the response array exists: a manifest whose frames are
    # missing or of the wrong size fails before anything of the grid's size is allocated.
    first = reader.read(manifest.frames[0])
    lit_counts = manifest.lit_counts()
    inverse_counts = np.zeros(lit_counts.shape, np.float32)
    np.divide(1, lit_counts, out=inverse_counts, where=lit_counts > 0)
    responses = np.zeros((height, width, len(offsets), 3), np.float32)
    # Only offsets shorter than the grid can join two grid points: a max_radius far beyond the
    # grid (1024 on a 4 x 3 grid, 3.3 million offsets) must not cost that much per frame.
    offset_index = np.flatnonzero((np.abs(offsets[:, 0]) < height) & (np.abs(offsets[:, 1]) < width))
    reachable = offsets[offset_index]
    bad_values, bad_frames, first_bad = 0, 0, None
    for done, frame in enumerate(manifest.frames):
        radiance, bad = first if done == 0 else reader.read(frame)
        if bad:
            bad_values += bad
            bad_frames += 1
            first_bad = first_bad or manifest.folder / frame.file
        # Every lit point q owns the points p = q - d within max_radius (multiplexed points are
        # more than 2 * max_radius apart, so no p is claimed twice in one frame).
        py = frame.lit[:, 0, None] - reachable[None, :, 0]
        px = frame.lit[:, 1, None] - reachable[None, :, 1]
        inside = (py >= 0) & (py < height) & (px >= 0) & (px < width)
        point, k = np.nonzero(inside)
        py, px = py[point, k], px[point, k]
        weight = inverse_counts[frame.lit[point, 0], frame.lit[point, 1]]
        responses[py, px, offset_index[k]] += radiance[py, px] * weight[:, None]
        if progress is not None:
            progress((done + 1) / len(manifest.frames))
    if bad_values:
        raise DatasetError(
            f"{first_bad}: NaN or Inf radiance ({bad_values} values in {bad_frames} frame(s); "
            f"this is the first)"
        )
    observed = reader.observed
    responses[~observed] = 0.0
    return cache.CachedArrays(responses=responses, lit_counts=lit_counts, observed=observed)


