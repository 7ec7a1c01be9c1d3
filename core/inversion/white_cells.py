"""A white run tallied into compact cells as it runs, for one structure: many more photons in
little memory (:mod:`.white_mc` keeps a record per estimate, 14-43 MB per 20 000 photons).

The run is :func:`.white_mc.run_white`'s, in chunks; each chunk's records are reduced to their
path length per *layer* of the structure and tallied into cells, then dropped. A cell is a pixel
class and a log-spaced bin of each layer's length: the pixel offsets ``(dy, dx)`` that the square's
symmetries (the dihedral group of order 8) map onto each other form a class, since a laterally
homogeneous slab lit over a square pixel and seen straight down has the same impulse response on
all of them; the lengths bins are 0 and ``[SHORTEST r^i, SHORTEST r^(i+1))`` with ``r =``
:data:`RATIO`. Each cell keeps its weight ``W = sum v``, the weighted mean ``mu`` (L,) and
covariance ``S`` (L, L) of its records' layer lengths, and the weight of each of :data:`BATCHES`
batches of chunks (for the run's own variance). With absorption ``a`` (L,) per layer, a cell
stands for ``sum v exp(-a . l) ~= W exp(-a . mu) (1 + a^T S a / 2)``: exact to second order in the
spread of ``a . l`` within the cell.

The error this adds (``tests/test_white_cells.py``): against the records' own sum on layers3's
structure, at most 0.03 % of E(r) for every ring r <= 11 and absorptions up to 0.5 per grid step
in every layer, up to 2 % where some layer absorbs 3 per grid step (light that long paths carry
through strongly absorbing layers, far below the noise there). At 200 000 photons a three-layer
structure fills about 0.3 million cells (25 MB) where its records took 300 MB.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..checked_arrays import DamagedFile, NotAFile, load_checked
from ..device import Device
from . import white_cache
from .forward import Structure
from .white_mc import DatabaseError, SlabOptics, WhiteDatabase, run_white

RATIO = 1.25
SHORTEST = 0.01
"""Grid steps: the lowest length bin's start (shorter lengths share it)."""
BATCHES = 16
"""Batches of chunks whose spread gives the run's own variance (itself uncertain by about 18 %)."""
CHUNK_PHOTONS = 20_000
"""Photons a chunk's records hold at once (about 30 MB of records)."""
FORMAT_VERSION = 2
_ARRAYS = ("photons", "cell_class", "weight", "mean", "spread", "batch_weight", "seconds")
GROWTH = 1.25
"""Factor by which the tally's arrays grow when full."""
_LEVELS = 64
"""Length bins per layer, 0 included: SHORTEST * RATIO^62 is about 10^4 grid steps."""


def pixel_classes(reach: int) -> np.ndarray:
    """((2 reach + 1)^2,) int64: the class of each pixel offset ``(dy + reach) * side + dx + reach``
    under the square's symmetries: ``hi (hi + 1) / 2 + lo`` of ``lo, hi`` = the smaller and larger
    of ``|dy|, |dx|``."""
    offsets = np.arange(-reach, reach + 1)
    dy, dx = np.meshgrid(offsets, offsets, indexing="ij")
    low, high = np.minimum(np.abs(dy), np.abs(dx)), np.maximum(np.abs(dy), np.abs(dx))
    return (high * (high + 1) // 2 + low).ravel()


@dataclass(frozen=True, eq=False)
class CellDatabase:
    """A white run tallied for one structure.

    Attributes
    ----------
    optics, starts
        What it was run for: the slab, and the structure's first bin of each layer.
    photons
        Photons traced.
    cell_class
        (M,) int64 pixel class of each cell (:func:`pixel_classes`).
    weight
        (M,) float64 ``W``: the cell's records' estimates without absorption, summed.
    mean, spread
        (M, L) and (M, L, L) float64: the weighted mean and covariance of its records' path length
        in each layer, grid steps.
    batch_weight
        (BATCHES, M) float32: ``W`` of each batch of chunks.
    seconds
        Time the run took.
    """

    optics: SlabOptics
    starts: tuple[int, ...]
    photons: int
    cell_class: np.ndarray
    weight: np.ndarray
    mean: np.ndarray
    spread: np.ndarray
    batch_weight: np.ndarray
    seconds: float


def run_cells(optics: SlabOptics, structure: Structure, photons: int, seed: int = 0,
              progress=None, device: Device | None = None) -> CellDatabase:
    """Trace ``photons`` (rounded up to chunks of :data:`CHUNK_PHOTONS` and whole blocks) without
    absorption and tally them for ``structure``; ``progress(fraction)`` after each chunk (raise
    from it to cancel). Chunk ``k`` runs on seed ``seed + (k << 32)``: its own random streams. On a
    CUDA ``device`` the cells are tallied on the GPU as the photons are traced
    (:func:`.cells_cuda.run_cells_cuda`)."""
    if device is not None and device.is_cuda:
        from .cells_cuda import run_cells_cuda

        return run_cells_cuda(optics, structure, photons, seed, progress)
    start = time.perf_counter()
    chunks = BATCHES * max(1, -(-photons // (CHUNK_PHOTONS * BATCHES)))
    per_chunk = -(-photons // chunks)
    classes = pixel_classes(optics.reach)
    cells = _Tally(moment_columns(structure.layers))
    traced = 0
    for chunk in range(chunks):
        records = run_white(optics, per_chunk, seed + (chunk << 32), device=device)
        traced += records.photons
        unique, moments = tally_records(records, structure, classes)
        del records
        cells.add(unique, moments, chunk % BATCHES)
        if progress is not None:
            progress((chunk + 1) / chunks)
    keys, sums, batch_weight = cells.arrays()
    del cells
    return cell_moments(optics, structure, traced, keys, sums, batch_weight, time.perf_counter() - start)


def moment_columns(layers: int) -> int:
    """Moment sums a cell keeps for ``layers`` layers: its weight, each layer's weighted length and
    each product of two layers' lengths (``k <= j``)."""
    return 1 + layers + layers * (layers + 1) // 2


def tally_records(records: WhiteDatabase, structure: Structure, classes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(keys, moments)``: the cells that ``records`` fall in for ``structure`` (sorted, distinct
    int64 keys: the pixel class, then each layer's length bin, :data:`_LEVELS` to a layer) and each
    cell's moment sums ``(cells, moment_columns(L))`` float64 (:class:`_Tally`'s columns);
    ``classes`` is :func:`pixel_classes` of the records' reach."""
    layers = structure.layers
    lengths = np.add.reduceat(records.lengths, np.asarray(structure.starts), axis=1, dtype=np.float64)
    key = classes[records.pixel].astype(np.int64)
    for k in range(layers):
        key = key * _LEVELS + _length_bin(lengths[:, k])
    # One weighted sum per column (no (records, columns) array).
    unique, inverse = np.unique(key, return_inverse=True)
    value = records.value.astype(np.float64)
    moments = np.empty((len(unique), moment_columns(layers)))
    moments[:, 0] = np.bincount(inverse, value, len(unique))
    for k in range(layers):
        moments[:, 1 + k] = np.bincount(inverse, value * lengths[:, k], len(unique))
    for column, (k, j) in enumerate(zip(*np.triu_indices(layers)), start=1 + layers):
        moments[:, column] = np.bincount(inverse, value * lengths[:, k] * lengths[:, j], len(unique))
    return unique, moments


def cell_moments(optics: SlabOptics, structure: Structure, traced: int, keys: np.ndarray, sums: np.ndarray,
                 batch_weight: np.ndarray, seconds: float) -> CellDatabase:
    """The database of cells ``keys`` (M,) with moment sums ``sums`` (M, columns) and batch weights
    ``(M, BATCHES)`` (:class:`_Tally`'s arrays): the sums made means and covariances."""
    layers = structure.layers
    weight = sums[:, 0].copy()
    mean = sums[:, 1:1 + layers] / weight[:, None]
    spread = np.empty((len(weight), layers, layers))
    for column, (k, j) in enumerate(zip(*np.triu_indices(layers)), start=1 + layers):
        spread[:, k, j] = sums[:, column] / weight - mean[:, k] * mean[:, j]
        spread[:, j, k] = spread[:, k, j]
    return CellDatabase(optics, tuple(structure.starts), traced, keys // _LEVELS ** layers, weight, mean, spread,
                        np.ascontiguousarray(batch_weight.T), seconds)


def cells_path(optics: SlabOptics, structure: Structure, photons: int, seed: int) -> Path:
    """Where the cells of these optics and structure live in the user cache (among the white
    databases, under their size limit)."""
    text = json.dumps({"records": optics.key(photons, seed), "starts": list(structure.starts), "cells": FORMAT_VERSION,
                       "ratio": RATIO, "shortest": SHORTEST, "batches": BATCHES, "chunk": CHUNK_PHOTONS})
    return white_cache.cache_folder() / f"{hashlib.sha256(text.encode()).hexdigest()[:24]}.npz"


def cell_database(optics: SlabOptics, structure: Structure, photons: int, seed: int = 0, use_cache: bool = True,
                  progress=None, device: Device | None = None) -> CellDatabase:
    """The cells of ``optics`` and ``structure`` from the user cache (:mod:`.white_cache`), or run
    (:func:`run_cells`, on ``device``) and cached atomically, the least recently used databases then dropped down
    to the cache's limit. A cached file that does not hold what this run would (damaged, another
    version's) is run again and replaced."""
    path = cells_path(optics, structure, photons, seed)
    limit = white_cache.cache_limit() if use_cache else 0  # a bad setting is told before the run
    if use_cache and (cells := _cached(path, optics, structure)) is not None:
        white_cache.mark_used(path)
        return cells
    cells = run_cells(optics, structure, photons, seed, progress, device)
    if use_cache:
        white_cache.store(path, path.stem, {"photons": np.int64(cells.photons), "cell_class": cells.cell_class,
                                            "weight": cells.weight, "mean": cells.mean, "spread": cells.spread,
                                            "batch_weight": cells.batch_weight, "seconds": np.float64(cells.seconds)},
                          limit)
    return cells


def _cached(path: Path, optics: SlabOptics, structure: Structure) -> CellDatabase | None:
    """The cells stored at ``path`` (:mod:`..checked_arrays`: with their run's key and digest), or
    None when there are none or they are not what a run of these optics and structure holds
    (damaged, edited, another run's: run again). DatabaseError naming the file for what is not a
    regular file (read, a FIFO blocked for good)."""
    try:
        arrays = load_checked(path, path.stem, _ARRAYS)
    except NotAFile as error:
        raise DatabaseError(f"{path}: not a white Monte Carlo database ({error}); remove it to rerun") from None
    except DamagedFile:
        return None
    if arrays is None:
        return None
    layers, cells = structure.layers, len(arrays["weight"])
    shapes = {"photons": (), "cell_class": (cells,), "weight": (cells,), "mean": (cells, layers),
              "spread": (cells, layers, layers), "batch_weight": (BATCHES, cells), "seconds": ()}
    if any(arrays[name].shape != shape for name, shape in shapes.items()) or arrays["batch_weight"].dtype != np.float32 \
            or not all(
            np.isfinite(arrays[name]).all() for name in ("weight", "mean", "spread", "batch_weight")):
        return None
    classes = pixel_classes(optics.reach).max() + 1
    if cells and (arrays["cell_class"].min() < 0 or arrays["cell_class"].max() >= classes
                  or arrays["weight"].min() <= 0 or int(arrays["photons"]) <= 0):
        return None
    return CellDatabase(optics, tuple(structure.starts), int(arrays["photons"]), arrays["cell_class"].astype(np.int64),
                        arrays["weight"], arrays["mean"], arrays["spread"], arrays["batch_weight"],
                        float(arrays["seconds"]))


def _length_bin(length: np.ndarray) -> np.ndarray:
    """(n,) int64 bin of each length (grid steps): 0 for none, else 1 + the log-spaced bin."""
    bins = np.zeros(len(length), np.int64)
    positive = length > 0
    scaled = np.log(np.maximum(length[positive], SHORTEST) / SHORTEST) / math.log(RATIO)
    bins[positive] = 1 + np.minimum(scaled.astype(np.int64), _LEVELS - 2)
    return bins


class _Tally:
    """Cells as they fill: keys, moment sums (``columns`` per cell: the weight, then the weighted
    sums of each layer's length and of each product of two, ``k <= j``) and each batch's weight, a
    row per cell, in arrays that grow in place (``ndarray.resize``: a reallocation, not a second
    copy beside the first); ``order`` sorts the keys, so a chunk's cells are found by binary search."""

    def __init__(self, columns: int):
        self.columns = columns
        self.size = 0
        self.keys = np.zeros(0, np.int64)
        self.sums = np.zeros((0, columns))
        self.batches = np.zeros((0, BATCHES), np.float32)
        self.order = np.zeros(0, np.int64)

    def add(self, keys: np.ndarray, sums: np.ndarray, batch: int) -> None:
        """Add a chunk's cells (``keys`` sorted and distinct, ``sums`` a row each) of ``batch``."""
        if self.size:
            ordered = self.keys[self.order]
            place = np.minimum(np.searchsorted(ordered, keys), self.size - 1)
            found = ordered[place] == keys
            del ordered
        else:
            place, found = np.zeros(len(keys), np.int64), np.zeros(len(keys), bool)
        rows = self.order[place[found]]
        self.sums[rows] += sums[found]
        self.batches[rows, batch] += sums[found, 0]
        new = ~found
        count = int(new.sum())
        if self.size + count > len(self.keys):
            self._grow(self.size + count)
        end = self.size + count
        self.keys[self.size:end] = keys[new]
        self.sums[self.size:end] = sums[new]
        self.batches[self.size:end] = 0.0
        self.batches[self.size:end, batch] = sums[new, 0]
        self.size = end
        self.order = np.argsort(self.keys[:end], kind="stable")

    def _grow(self, needed: int) -> None:
        capacity = max(needed, int(GROWTH * len(self.keys)), 1024)
        for array in (self.keys, self.sums, self.batches):
            array.resize((capacity, *array.shape[1:]), refcheck=False)  # new rows are zero

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(keys, sums, batch weights)`` of the cells filled: views trimmed to them, batches
        ``(cells, BATCHES)``."""
        return self.keys[:self.size], self.sums[:self.size], self.batches[:self.size]
