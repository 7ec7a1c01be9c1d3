"""Assembling a dataset's response array from its frames, on every core and in bounded memory.

Each frame is decoded once per *band* of grid rows (a grid-space frame decodes only the band's
rows; the library decodes its line chunks on every core), in a thread that runs one frame ahead of
the scatter; the scatter is compiled and parallel over the frame's lit points and offsets (every
``(p, k)`` pair it writes is distinct within a frame: multiplexed points are more than
``2 max_radius`` apart). A response array that fits the memory budget is one band, kept in
memory; a larger one is built band by band into the dataset's store (:mod:`.response_store`),
each band as many store tiles high as fit a quarter of the budget, and read from there.

Progress runs over every phase: reading the frames (per band) and writing the store.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numba
import numpy as np
import OpenEXR

from ..errors import DatasetError
from .frames import FrameReader
from .manifest import Manifest
from .response_store import StoreWriter, store_tile

ProgressCallback = Callable[[float], None]
WRITE_SHARE = 0.1
"""Share of an in-memory open's progress given to writing its store."""


@dataclass(frozen=True, eq=False)
class Assembled:
    """An in-memory assembly: (H, W, K, 3) float32 responses, (H, W) int32 lit counts, (H, W)
    bool observed and (H, W, 3) float32 steady state (NaN where unobserved)."""

    responses: np.ndarray
    lit_counts: np.ndarray
    observed: np.ndarray
    steady: np.ndarray


class Assembler:
    """Reads a dataset's frames into responses over the offsets ``offsets`` ((K, 2) int64)."""

    def __init__(self, manifest: Manifest, offsets: np.ndarray, allow_outside: bool = False):
        self.manifest = manifest
        self.height, self.width = manifest.height, manifest.width
        self.offsets = offsets
        self.reader = FrameReader(manifest, allow_outside)
        # A manifest whose frames are missing or of the wrong size fails before anything of the
        # grid's size is allocated.
        self.reader.check(manifest.frames[0])
        self.lit_counts = manifest.lit_counts()
        self.inverse_counts = np.zeros(self.lit_counts.shape, np.float32)
        np.divide(1, self.lit_counts, out=self.inverse_counts, where=self.lit_counts > 0)
        # Only offsets shorter than the grid can join two grid points: a max_radius far beyond the
        # grid (1024 on a 4 x 3 grid, 3.3 million offsets) must not cost that much per frame.
        reachable = np.flatnonzero((np.abs(offsets[:, 0]) < self.height) & (np.abs(offsets[:, 1]) < self.width))
        # In raster order of the offsets: around one lit point the writes then walk the band's
        # points row by row (a point's responses are one block), not the rings' order across it.
        self.offset_index = reachable[np.lexsort((-offsets[reachable, 1], -offsets[reachable, 0]))]
        self.dy = np.ascontiguousarray(offsets[self.offset_index, 0])
        self.dx = np.ascontiguousarray(offsets[self.offset_index, 1])

    @property
    def observed(self) -> np.ndarray:
        return self.reader.observed

    def band(self, row0: int, row1: int, progress: Callable[[float], None] | None = None) -> np.ndarray:
        """Responses of grid rows ``row0 .. row1``: (rows, W, K, 3) float32, 0 at unobserved points.

        ``progress`` gets the fraction of frames read. Raises DatasetError naming the first frame
        with NaN or Inf values."""
        frames = self.manifest.frames
        bad_values, bad_frames, first_bad = 0, 0, None
        with _decoding_threads(), ThreadPoolExecutor(max_workers=1) as ahead:
            pending = ahead.submit(self.reader.read, frames[0], (row0, row1))
            pending.result()  # a first frame that cannot be read fails before the band is allocated
            responses = np.zeros((row1 - row0, self.width, len(self.offsets), 3), np.float32)
            for done, frame in enumerate(frames):
                radiance, bad = pending.result()
                if done + 1 < len(frames):
                    pending = ahead.submit(self.reader.read, frames[done + 1], (row0, row1))
                if bad:
                    bad_values += bad
                    bad_frames += 1
                    first_bad = first_bad or self.manifest.folder / frame.file
                _scatter(responses, radiance, frame.lit, self.dy, self.dx, self.offset_index, self.inverse_counts,
                         row0)
                if progress is not None:
                    progress((done + 1) / len(frames))
        if bad_values:
            raise DatasetError(f"{first_bad}: NaN or Inf radiance ({bad_values} values in {bad_frames} frame(s); "
                               "this is the first)")
        responses[~self.observed[row0:row1]] = 0.0
        return responses

    def steady(self, band: np.ndarray, row0: int) -> np.ndarray:
        """The steady state of a band's rows: (rows, W, 3) float32, NaN where unobserved."""
        total = band.sum(axis=2, dtype=np.float64)
        total[~self.observed[row0:row0 + len(band)]] = np.nan
        return total.astype(np.float32)


def assemble_in_memory(assembler: Assembler, progress: ProgressCallback | None = None,
                       share: float = 1.0) -> Assembled:
    """The whole response array at once; ``progress`` goes from 0 to ``share``."""
    report = None if progress is None else (lambda fraction: progress(share * fraction))
    responses = assembler.band(0, assembler.height, report)
    return Assembled(responses, assembler.lit_counts, assembler.observed, assembler.steady(responses, 0))


def write_assembled(writer: StoreWriter, assembled: Assembled, progress: ProgressCallback | None = None,
                    start: float = 0.0) -> None:
    """Write an in-memory assembly into a store, tile row by tile row; progress from ``start`` to 1."""
    height = assembled.responses.shape[0]
    for row in range(0, height, writer.tile):
        writer.write_rows(row, assembled.responses[row:row + writer.tile])
        if progress is not None:
            progress(start + (1.0 - start) * min(row + writer.tile, height) / height)
    writer.write_small(assembled.lit_counts, assembled.observed, assembled.steady)


def assemble_into_store(assembler: Assembler, writer: StoreWriter, budget: int,
                        progress: ProgressCallback | None = None) -> None:
    """Build the store band by band, each band a whole number of tiles within a quarter of
    ``budget`` (writing a band encodes copies of its chunks beside it)."""
    row_bytes = assembler.width * len(assembler.offsets) * 12
    rows = max(writer.tile, (budget // 4 // max(row_bytes, 1)) // writer.tile * writer.tile)
    height = assembler.height
    steady = np.empty((height, assembler.width, 3), np.float32)
    for row0 in range(0, height, rows):
        row1 = min(row0 + rows, height)
        report = None if progress is None else (
            lambda fraction, row0=row0, row1=row1: progress((row0 + fraction * (row1 - row0)) / height))
        band = assembler.band(row0, row1, report)
        writer.write_rows(row0, band)
        steady[row0:row1] = assembler.steady(band, row0)
        del band
    writer.write_small(assembler.lit_counts, assembler.observed, steady)


@contextmanager
def _decoding_threads() -> Iterator[None]:
    """OpenEXR decodes a file's line chunks on every core while a frame is read."""
    before = OpenEXR.global_thread_count()
    OpenEXR.set_global_thread_count(os.cpu_count() or 1)
    try:
        yield
    finally:
        OpenEXR.set_global_thread_count(before)


@numba.njit(cache=True, nogil=True)
def _scatter(responses, radiance, lit, dy, dx, offset_index, inverse_counts, row0):  # pragma: no cover - compiled
    """responses[p - row0, k] += radiance[p - row0] / lit_count(q) for every lit point q of a
    frame and offset d = offsets[k] with p = q - d inside the band (rows row0 ..).

    Serial, without the GIL: it runs beside the next frame's decoding (which takes longer and
    uses the library's threads), and a parallel launch per frame costs more than it gives."""
    rows, width = responses.shape[0], responses.shape[1]
    reach = 0
    for j in range(dy.size):
        reach = max(reach, abs(dy[j]))
    for i in range(lit.shape[0]):
        qy = lit[i, 0]
        qx = lit[i, 1]
        if qy + reach < row0 or qy - reach >= row0 + rows:
            continue  # no point of the band within reach
        weight = inverse_counts[qy, qx]
        for j in range(dy.size):
            py = qy - dy[j] - row0
            px = qx - dx[j]
            if py >= 0 and py < rows and px >= 0 and px < width:
                k = offset_index[j]
                for c in range(3):
                    responses[py, px, k, c] += radiance[py, px, c] * weight

