"""E(r) and its derivatives from a white run tallied in cells (:mod:`.white_cells`): the forward
model of the fits at the end of an inversion.

A cell (its weight ``W``, mean ``mu`` and covariance ``S`` of the layers' path lengths) stands for
``W exp(-a . mu) (1 + a^T S a / 2)`` at absorption ``a`` per layer (:mod:`.white_cells`). A fit
evaluates this over every cell a few thousand times, so the kernels are written for speed; their
results are the same sums as a plain loop over the cells, to rounding (1e-14 relative: the sums are
taken in vector lanes, in another order):

- cells of a pixel class that no ring weighs (the corners of the database's square beyond the
  outermost ring: a third of layers3's) are dropped, as they change no E(r);
- the cells are sorted by class and summed into scalars a class at a time;
- each cell's means and upper triangle of ``S`` are stored in float32 columns
  (:data:`PACKED_COLUMNS`, M), padded with zeros to :data:`MAX_CELL_LAYERS` layers, so the
  per-layer loops are written out (a loop over a layer count known only at run time kept ``S a``
  in memory and took three times as long on layers3's 0.67 million cells);
- the loop over a class's cells is vectorised by LLVM (four cells an instruction with AVX2): its
  ``exp`` is :func:`.vector_exp.vector_exp`, arithmetic where ``math.exp`` is a call that kept the
  loop scalar, its sums may be reassociated (fast-math ``reassoc``), and its index is unsigned
  (numba wraps a negative signed index around, a select per access that kept the loop from
  vectorising). On layers3's 436 000 weighed cells an evaluation with derivatives takes 2.5-2.9
  ms where the scalar loop took 7.6-8.2 ms (alternated, one thread, load 1.5-2).
"""

from __future__ import annotations

import numba
import numpy as np

from .forward import Structure, embedded_rings, ring_matrix
from .vector_exp import vector_exp
from .white_cells import CellDatabase, pixel_classes

MAX_CELL_LAYERS = 4
"""Layers a cell's row holds (:data:`.settings.MAX_LAYERS`); fewer are padded with zeros."""
_UPPER = np.triu_indices(MAX_CELL_LAYERS)
PACKED_COLUMNS = MAX_CELL_LAYERS + len(_UPPER[0])
"""float32 columns of a cell: the mean length in each layer, then the upper triangle of ``S`` by rows."""


def packed_cells(mean: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """(PACKED_COLUMNS, M) float32 columns of cells whose ``mean`` (M, L) and ``spread`` (M, L, L)
    are in grid steps (squared), zero beyond ``L``: a length's relative rounding (6e-8) moves
    ``a . mu`` by far less than the cells' own approximation. A column per quantity, so that
    consecutive cells' values are adjacent (the vectorised loop loads four at once). ValueError for
    more than :data:`MAX_CELL_LAYERS` layers."""
    layers = mean.shape[1]
    if layers > MAX_CELL_LAYERS:
        raise ValueError(f"cells hold at most {MAX_CELL_LAYERS} layers, got {layers}")
    packed = np.zeros((PACKED_COLUMNS, len(mean)), np.float32)
    packed[:layers] = mean.T
    for column, (k, j) in enumerate(zip(*_UPPER), start=MAX_CELL_LAYERS):
        if j < layers:
            packed[column] = spread[:, k, j]
    return packed


class CellForward:
    """E(r) and its derivatives from a :class:`.white_cells.CellDatabase`, as
    :class:`.forward.Forward` gives them from records (the same interface: :meth:`profile`,
    :meth:`variance`, :meth:`covariance`, :attr:`reached`)."""

    def __init__(self, database: CellDatabase, structure: Structure, radii, thickness: float = 1.0,
                 antialias: bool = False, ring_weights: np.ndarray | None = None):
        if tuple(structure.starts) != database.starts:
            raise ValueError(f"cells tallied for layers from {database.starts}, not {structure.starts}")
        self.database = database
        self.structure = structure
        self.radii = np.asarray(radii, np.float64)
        reach = database.optics.reach
        rings = (ring_matrix(self.radii, reach, thickness, antialias) if ring_weights is None
                 else embedded_rings(ring_weights, reach))
        classes = pixel_classes(reach)
        count = np.bincount(classes)
        # Every pixel of a class has the class's response: a ring weighs the class's mean pixel.
        self.rings = np.stack([np.bincount(classes, row, len(count)) for row in rings]) / count
        weighed = np.any(self.rings != 0.0, axis=0)
        order = np.argsort(database.cell_class, kind="stable")
        order = order[weighed[database.cell_class[order]]]
        self._starts = np.searchsorted(database.cell_class[order], np.arange(len(count) + 1)).astype(np.uint64)
        self._weight = database.weight[order]
        self._packed = packed_cells(database.mean[order], database.spread[order])
        self._batches = np.ascontiguousarray(database.batch_weight[:, order].T)
        reached = self.profile(np.zeros(structure.layers)) > 0
        self.reached = int(np.argmin(reached)) if not reached.all() else len(reached)

    def _padded(self, mua) -> np.ndarray:
        """(MAX_CELL_LAYERS,) float64 ``mua`` (L,) with zeros for the layers a row pads."""
        padded = np.zeros(MAX_CELL_LAYERS)
        padded[:self.structure.layers] = mua
        return padded

    def profile(self, mua: np.ndarray, derivatives: bool = False):
        """E(r) (R,) for absorption ``mua`` (L,) per layer; with ``derivatives``, also
        dE/dmua (R, L)."""
        per_class, slopes = _cell_kernel(self._starts, self._weight, self._packed, self._padded(mua))
        scale = 1.0 / self.database.photons
        profile = self.rings @ per_class * scale
        if not derivatives:
            return profile
        return profile, (self.rings @ slopes[:self.structure.layers].T) * scale

    def variance(self, mua: np.ndarray) -> np.ndarray:
        """(R,) variance of :meth:`profile` from the run's batches (:meth:`covariance` of one channel)."""
        return self.covariance(np.asarray(mua, np.float64)[None])[:, 0, 0]

    def covariance(self, mua: np.ndarray, rings: int | None = None) -> np.ndarray:
        """(rings, C, C) covariance between the channels' :meth:`profile` at absorptions ``mua``
        (C, L) over the first ``rings`` rings, from the spread of the batches' profiles (each
        batch's cells weighted by its own share of their weight); the channels share the photons,
        so they covary."""
        mua = np.asarray(mua, np.float64)
        rings = len(self.radii) if rings is None else rings
        batches = self._batches.shape[1]
        per_batch = np.stack([
            _batch_kernel(self._starts, self._batches, self._packed, self._padded(absorption))
            @ self.rings[:rings].T for absorption in mua]) * (batches / self.database.photons)
        centred = per_batch - per_batch.mean(axis=1, keepdims=True)
        # The mean of B batch estimates has the covariance of one over B.
        return np.einsum("cbr,dbr->rcd", centred, centred) / (batches - 1) / batches


@numba.njit(cache=True, nogil=True, inline="always")
def _attenuation(packed, i, a0, a1, a2, a3):
    """Cell ``i``'s ``(exp(-a . mu), 1 + a^T S a / 2, (S a)_0, .., (S a)_3)`` from its column of
    ``packed`` (:func:`packed_cells`) at absorptions ``a0 .. a3``."""
    t0 = packed[4, i] * a0 + packed[5, i] * a1 + packed[6, i] * a2 + packed[7, i] * a3
    t1 = packed[5, i] * a0 + packed[8, i] * a1 + packed[9, i] * a2 + packed[10, i] * a3
    t2 = packed[6, i] * a0 + packed[9, i] * a1 + packed[11, i] * a2 + packed[12, i] * a3
    t3 = packed[7, i] * a0 + packed[10, i] * a1 + packed[12, i] * a2 + packed[13, i] * a3
    correction = 1.0 + 0.5 * (a0 * t0 + a1 * t1 + a2 * t2 + a3 * t3)
    exponent = packed[0, i] * a0 + packed[1, i] * a1 + packed[2, i] * a2 + packed[3, i] * a3
    return vector_exp(-exponent), correction, t0, t1, t2, t3


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "nsz", "arcp"})
def _cell_kernel(starts, weight, packed, mua):
    """Per pixel class (cells ``starts[c]:starts[c + 1]``, unsigned), the cells' ``W exp(-a . mu)
    (1 + a^T S a / 2)`` summed ((classes,)) and its derivative by each layer's absorption, ``W
    exp(-a . mu) ((S a)_k - mu_k (1 + a^T S a / 2))`` ((MAX_CELL_LAYERS, classes)), always (they
    cost a third more than the sums alone, and least squares asks for them at every step). Serial
    and without the GIL (the channels' fits run in threads)."""
    classes = starts.shape[0] - 1
    totals = np.zeros(classes)
    slopes = np.zeros((MAX_CELL_LAYERS, classes))
    a0, a1, a2, a3 = mua[0], mua[1], mua[2], mua[3]
    for c in range(classes):
        total, s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0, 0.0
        for i in range(starts[c], starts[c + 1]):
            attenuation, correction, t0, t1, t2, t3 = _attenuation(packed, i, a0, a1, a2, a3)
            kept = weight[i] * attenuation
            total += kept * correction
            s0 += kept * (t0 - packed[0, i] * correction)
            s1 += kept * (t1 - packed[1, i] * correction)
            s2 += kept * (t2 - packed[2, i] * correction)
            s3 += kept * (t3 - packed[3, i] * correction)
        totals[c] = total
        slopes[0, c], slopes[1, c], slopes[2, c], slopes[3, c] = s0, s1, s2, s3
    return totals, slopes


@numba.njit(cache=True, nogil=True)
def _batch_kernel(starts, batches, packed, mua):
    """(B, classes): :func:`_cell_kernel`'s totals of each batch, whose cells weigh ``batches``
    (M, B), in one pass over the cells."""
    count = batches.shape[1]
    classes = starts.shape[0] - 1
    totals = np.zeros((count, classes))
    sums = np.zeros(count)
    a0, a1, a2, a3 = mua[0], mua[1], mua[2], mua[3]
    for c in range(classes):
        sums[:] = 0.0
        for i in range(starts[c], starts[c + 1]):
            attenuation, correction, _, _, _, _ = _attenuation(packed, i, a0, a1, a2, a3)
            factor = attenuation * correction
            for b in range(count):
                sums[b] += batches[i, b] * factor
        totals[:, c] = sums
    return totals
