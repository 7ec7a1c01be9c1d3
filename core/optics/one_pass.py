"""The maps' fits inside the stack's pass: :data:`.chunk_fit.CHUNK` pixels of a grid row at a time,
their rings and their spread (:func:`ringlight.core.rings.stack_spread.spread_row`), then at once
those pixels' node fits (:func:`.chunk_fit.node_fit_chunk`) while their profiles are in the core's
cache.

The fits read the same float32 E_r and SE(E_r) as :func:`.pixel_fit.fit_profiles` reads from
:func:`ringlight.core.rings.stack_spread.ring_stack_and_errors`, by the same compiled code, so the
maps equal theirs but for the order in which the compiler sums (within 1e-9 of a standard error,
``tests/test_optics_one_pass.py``). What this saves is the
(R, H, W, 3) images and errors written to memory and read back by the fits (two 61 MB arrays at
800 x 800, 8 rings), read by the fits across R planes per pixel.
"""

from __future__ import annotations

import numba
import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..errors import Cancelled
from ..kernel_cache import is_cached
from ..rings.stack_spread import band_members, spread_rings, spread_row
from .chunk_fit import CHUNK, chunk_scratch, node_fit_chunk
from .node_fit import fine_nodes
from .pixel_fit import coarse_nodes, fit_outputs
from .table import ProfileTable


def fit_in_one_pass(dataset: ImpulseDataset, radii: np.ndarray, table: ProfileTable, scale: np.ndarray,
                    floor: float, inflation: np.ndarray, progress=None, cancelled=None
                    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Node fits of every pixel and channel of ``dataset`` to its rings at ``radii`` (0, 1, ...,
    thickness 1) with their ring-spread standard errors, computed row by row in one pass.

    Parameters
    ----------
    dataset
        An open impulse dataset without replicates (the errors are the ring members' spread).
    radii
        (R,) the rings' radii, grid steps (:func:`.maps.profile_radii`).
    table
        The look-up table at ``radii``.
    scale
        (3,) the rig's scale per channel.
    floor, inflation
        The relative standard deviation added to every ring, and (R,) each ring's error factor
        (:func:`.pixel_data.pixel_profile`).
    progress
        ``progress(fraction)`` after each band of rows (may raise ``Cancelled``).
    cancelled
        ``cancelled() -> bool`` asked before each band; True raises
        :class:`ringlight.core.errors.Cancelled`.

    Returns
    -------
    fitted, complete
        ``fitted`` as :func:`.pixel_fit.fit_profiles` returns it (``estimator="nodes"``), (H, W, 3)
        arrays; ``complete`` (H, W) bool: every ring lies whole on the grid and lit.
    """
    rings = spread_rings(dataset, radii)
    nodes = fine_nodes(table)
    coarse = coarse_nodes(table.log_profile)
    height, width = dataset.grid_shape
    out = fit_outputs(height, width, 3, filled=False)  # the kernel writes every output
    complete = np.empty((height, width), bool)
    first, stop = rings.tables[0], rings.tables[1]
    whole = (stop - first).astype(np.int32)  # a default ring is one run of the offset axis
    scale = np.asarray(scale, np.float64)
    inflation = np.asarray(inflation, np.float64)
    for row0, row1 in dataset.bands():
        if cancelled is not None and cancelled():
            raise Cancelled("optical maps cancelled")
        counts = band_members(dataset, rings, row0, row1)
        _stack_fit_rows(np.ascontiguousarray(dataset.rows(row0, row1)), row0, *rings.kernel_arguments, counts, *nodes,
                        table.log_profile, coarse, table.u0, table.du, table.v0, table.dv, scale, float(floor),
                        inflation, out["u"], out["v"], out["cuu"], out["cuv"], out["cvv"], out["chi2"], out["rings"],
                        out["status"], out["node_steps"], whole, complete)
        if progress is not None:
            progress(row1 / height)
    return out, complete


def fits_compiled() -> bool:
    """Whether numba's cache holds the pass's kernel (false on a first run after an install or an
    update, when it compiles: about 30 s on two cores, 16 s before the chunks' lanes)."""
    return is_cached(_stack_fit_rows)


@numba.njit(parallel=True, cache=True, nogil=True)
def _stack_fit_rows(responses, row0, lit, dy, dx, first, stop, groups, ring_groups, counts, nodes, node_u0, node_du,
                    node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, scale, floor, inflation, u_out, v_out, cuu,
                    cuv, cvv, chi2_out, rings_out, status, steps, whole, complete):
    """The band of grid rows from ``row0`` (``responses`` (rows, W, K, 3) C-contiguous, ``counts``
    (R, rows, W) its rings' members), row by row: its rings and their spread, then its fits into
    the (H, W, 3) outputs; and ``complete`` (H, W): every ring has all its ``whole`` (R,) members."""
    rows, width, offsets = responses.shape[0], responses.shape[1], responses.shape[2]
    flat = responses.reshape(rows, width, offsets * 3)
    for y in numba.prange(rows):
        _stack_fit_row(flat[y], row0 + y, lit, dy, dx, first, stop, groups, ring_groups, counts[:, y:y + 1], nodes,
                       node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, scale, floor,
                       inflation, u_out, v_out, cuu, cuv, cvv, chi2_out, rings_out, status, steps)
        for x in range(width):
            whole_rings = True
            for r in range(whole.size):
                whole_rings = whole_rings and counts[r, y, x] == whole[r]
            complete[row0 + y, x] = whole_rings


@numba.njit(cache=True, nogil=True)
def _stack_fit_row(pixels, py, lit, dy, dx, first, stop, groups, ring_groups, counts, nodes, node_u0, node_du, node_v0,
                   node_dv, log_profile, coarse, u0, du, v0, dv, scale, floor, inflation, u_out, v_out, cuu, cuv, cvv,
                   chi2_out, rings_out, status, steps):
    """Grid row ``py``, :data:`.chunk_fit.CHUNK` pixels at a time: their rings and errors into a
    (3, R, CHUNK) scratch, channel by channel (as :func:`.chunk_fit.node_fit_chunk` reads them), then
    their fits (a function of its own outside the parallel loop: numba's trap, :mod:`.chunk_fit`)."""
    rings, width = first.size, pixels.shape[0]
    lanes = np.zeros((3, rings, CHUNK), np.float32)
    lane_errors = np.zeros((3, rings, CHUNK), np.float32)
    images = lanes.transpose(1, 2, 0)  # (R, CHUNK, 3): the same memory as spread_row writes it
    errors = lane_errors.transpose(1, 2, 0)
    scratch = chunk_scratch(3, rings)
    starts = np.full((3, 2), np.nan)  # each channel's fits start where the last chunk's ended
    for x0 in range(0, width, CHUNK):
        x1 = min(width, x0 + CHUNK)
        spread_row(pixels[x0:x1], py, x0, lit, dy, dx, first, stop, groups, ring_groups, counts[:, 0, x0:x1],
                   images[:, :x1 - x0], errors[:, :x1 - x0])
        node_fit_chunk(nodes, node_u0, node_du, node_v0, node_dv, log_profile, coarse, u0, du, v0, dv, lanes,
                       lane_errors, x1 - x0, scale, True, counts[:, :, x0:x1], floor, inflation, py, x0, starts, u_out,
                       v_out, cuu, cuv, cvv, chi2_out, rings_out, status, steps, scratch)
