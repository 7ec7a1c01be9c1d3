"""The disc of offsets around a grid point that a dataset's response array holds (its offset axis,
``|d| <= max_radius``, ordered by distance then angle), its size, and which of its entries are
valid (lit points inside the grid, seen from observed points)."""

from __future__ import annotations

import numba
import numpy as np


def fill_validity(lit: np.ndarray, observed: np.ndarray, offsets: np.ndarray, validity: np.ndarray,
                  row0: int) -> None:
    """Fill ``validity`` ((rows, W, K) uint8) with the :meth:`.impulse_dataset.ImpulseDataset.validity_rows` of grid rows
    ``row0 ..``, from the (H, W) bool lit and observed points and the (K, 2) offsets."""
    _fill_validity(np.ascontiguousarray(lit), np.ascontiguousarray(observed), np.ascontiguousarray(offsets[:, 0]),
                   np.ascontiguousarray(offsets[:, 1]), validity, row0)


@numba.njit(parallel=True, cache=True, nogil=True)
def _fill_validity(lit, observed, dy, dx, validity, row0):
    """validity[y - row0, x, k] for the rows row0 .. row0 + len(validity) (see ``validity``)."""
    height, width = lit.shape
    for row in numba.prange(validity.shape[0]):
        y = row0 + row
        for x in range(width):
            for k in range(dy.size):
                qy = y + dy[k]
                qx = x + dx[k]
                inside = 0 <= qy < height and 0 <= qx < width
                validity[row, x, k] = 1 if inside and observed[y, x] and lit[qy, qx] else 0


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
