"""Assembling a dataset's response array from its frames, on every core and in bounded memory.

Each frame is decoded once per *band* of grid rows by a pool of reader threads, which also mark
which offset each point of the band takes from the frame. A band of every row decodes whole
frames of just the channels read with the library's reader that releases the GIL, a frame a
thread; a band of some rows, or frames with more channels (RGBA, render layers), are decoded by
the library's selecting reader, which holds the GIL, so their line chunks are decoded on the
library's own threads instead (:func:`.exr.whole_file_reader`). Frames go in two batches that take
turns: while one is scattered, the readers fill the other. The scatter is compiled: it visits the
points in parallel over rows, adding each one's light from every frame of the batch into its
block of responses (one visit a batch rather than one scattered write a frame), with the block's
offsets in raster order: frames lit in raster order then fill neighbouring slots, which are put
in the array's order (by distance) once the band is complete (0.15 s for 1.3 GiB). On
``benchmarks/bench_scale.py``'s 256 px dataset this took the assembly from 6.5-7.7 s (one reader a
frame ahead, its owners marked between scatters) to 4.4-4.7 s, and then (frames decoded side by
side, half floats converted by a compiled table lookup, slots in raster order) from 5.0-6.1 s to
3.7-5.1 s in alternated runs of this machine, the decode of every frame alone on both cores being
1.5-2.3 s. A response array that fits the memory budget is one
band, kept in memory; a larger one is built band by band into the dataset's store
(:mod:`.response_store`), each band as many store tiles high as fit :data:`BAND_SHARE` of the
budget, and read from there. Every band decodes its rows of every frame, so a pass costs each
frame's opening and header again: fewer, larger bands are faster (a 256 px dataset in 16 bands
took 33-40 s, in 8 bands 23-24 s).

Progress runs over every phase: reading the frames (per band) and writing the store.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import OpenEXR

from ..errors import DatasetError, ProgressCallback
from ..phases import phase
from .exr import whole_file_reader
from .exr_header import quiet_library
from .cache import IDENTITY_FIELDS
from .file_batch import reader_count
from .frame_batch import READ_ALONE, BatchDecoder, owners
from .frames import FrameReader
from .manifest import Manifest
from .memory import zeroed
from .response_store import StoreWriter
from .scatter import scatter, slots_to_offsets

BATCH_BYTES = 256 * 2**20
"""Frame rows waiting for the scatter, both batches together (radiance and owner: 14 or 16 bytes a
point)."""
BATCH_FRAMES = 8192
"""Most frames of a batch (a batch of a small grid's 100 000 frames, when each held a queued read,
held 640 MB of them). Its reads are queued in groups, each group one run of compiled calls
(:class:`.frame_batch.BatchDecoder`) with about 0.15 ms of Python around it: groups of 1024
frames (a batch of 8192 on two reader threads) rather than 128 took an open of 100 000 small
frames from 14.9-16.7 to 11.8-12.4 us of CPU a frame."""
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
    """Reads a dataset's frames into responses over the offsets ``offsets`` ((K, 2) int64), with the
    frames' ``channels`` (:func:`.frames.dataset_channels`) when the caller knows them."""

    def __init__(self, manifest: Manifest, offsets: np.ndarray, allow_outside: bool = False,
                 channels: tuple[str, ...] | None = None):
        self.manifest = manifest
        self.height, self.width = manifest.height, manifest.width
        self.offsets = offsets
        self.reader = FrameReader(manifest, allow_outside, channels)
        # A manifest whose frames are missing or of the wrong size fails before anything of the
        # grid's size is allocated.
        first, passed = self.reader.check(manifest.frames[0])
        # Whether frames read whole decode side by side (the first frame's header stands for all).
        self.whole_file_reader = whole_file_reader(first, self.reader.channels)
        # Runs of small frames of the first frame's header decode in one compiled call each.
        self.batches = BatchDecoder(self.reader, passed)
        self.identities = np.full((len(manifest.frames), IDENTITY_FIELDS), -1, np.int64)
        """(F, 4) int64: each frame file's identity as it was read (:func:`.cache.files_key`)."""
        self.lit_counts = manifest.lit_counts()
        self.inverse_counts = np.zeros(self.lit_counts.shape, np.float32)
        np.divide(1, self.lit_counts, out=self.inverse_counts, where=self.lit_counts > 0)
        # Only offsets shorter than the grid can join two grid points: a max_radius far beyond the
        # grid (1024 on a 4 x 3 grid, 3.3 million offsets) must not cost that much per frame.
        reachable = np.flatnonzero((np.abs(offsets[:, 0]) < self.height) & (np.abs(offsets[:, 1]) < self.width))
        # A band is scattered with each point's offsets in raster order ([dy, dx] row by row) and
        # put in the array's order (by distance) at the end: frames lit in raster order (parallel
        # and one-point captures alike) then fill a point's block in runs of neighbouring slots
        # instead of a slot in every cache line.
        raster = np.lexsort((offsets[:, 1], offsets[:, 0]))
        self.slot_of = np.empty(len(offsets), np.int64)
        self.slot_of[raster] = np.arange(len(offsets))
        self.offset_index = self.slot_of[reachable]
        self.dy = np.ascontiguousarray(offsets[reachable, 0])
        self.dx = np.ascontiguousarray(offsets[reachable, 1])

    @property
    def observed(self) -> np.ndarray:
        return self.reader.observed

    def band(self, row0: int, row1: int, progress: Callable[[float], None] | None = None,
             batch_bytes: int = BATCH_BYTES) -> tuple[np.ndarray, np.ndarray]:
        """Responses of grid rows ``row0 .. row1``: (rows, W, K, 3) float32, 0 at unobserved points,
        and their steady state (rows, W, 3) float32 (NaN at unobserved points), summed as the
        responses are.

        Frames are scattered in batches (:class:`_Batch`; two of them, together up to
        ``batch_bytes``), point by point: a point's responses are one block, which a batch fills
        in one visit instead of one visit a frame. While one batch is scattered on every core,
        :func:`.file_batch.reader_count` threads decode the next one's frames and mark their owners.
        ``progress`` gets the fraction of frames read. Raises DatasetError naming the first frame
        with NaN or Inf values, or the first that cannot be read."""
        frames = self.manifest.frames
        rows = row1 - row0
        point_bytes = _Batch.point_bytes(len(self.offsets))
        size = int(np.clip(batch_bytes // 2 // max(rows * self.width * point_bytes, 1), 1,
                           min(len(frames), BATCH_FRAMES)))
        starts = range(0, len(frames), size)
        bad_values, bad_frames, first_bad = 0, 0, None
        done = 0
        whole = rows == self.height or self.reader.mapping is not None  # camera frames decode whole
        library_threads = 0 if whole and self.whole_file_reader else os.cpu_count() or 1
        readers = reader_count()
        with _decoding_threads(library_threads), ThreadPoolExecutor(max_workers=readers) as pool:
            def submit(index: int) -> list:
                """Queue the reads of batch ``index`` into buffer ``index % 2``: a task per group
                of frames, not a future per frame (100 000 of them took 6 s to make and wait on)."""
                batch, start = batches[index % 2], starts[index]
                count = min(size, len(frames) - start)
                group = max(1, -(-count // (4 * readers)))
                return [pool.submit(self._load_group, batch, slot, start + slot, start + min(slot + group, count),
                                    row0, row1, first if index == slot == 0 else None)
                        for slot in range(0, count, group)]

            # Fails before the band is allocated.
            first = self.reader.read(frames[0], (row0, row1), identity=self.identities[0])
            batches = [_Batch(size, rows, self.width, len(self.offsets)) for _ in range(min(2, len(starts)))]
            responses = zeroed((rows, self.width, len(self.offsets), 3), np.float32)
            steady = np.zeros((rows, self.width, 3), np.float64)
            pending, queued = submit(0), []
            try:
                for index in range(len(starts)):
                    queued = submit(index + 1) if index + 1 < len(starts) else []
                    loaded = 0
                    for future in pending:
                        counts = future.result()
                        if any(counts):  # a frame with NaN or Inf values (a step a frame only then)
                            for offset, bad in enumerate(counts):
                                if bad:
                                    bad_values += bad
                                    bad_frames += 1
                                    first_bad = first_bad or \
                                        self.manifest.folder / frames[starts[index] + loaded + offset].file
                        loaded += len(counts)
                        if progress is not None:
                            progress((done + loaded) / len(frames))
                    done += loaded
                    batch = batches[index % 2]
                    scatter(responses, steady, batch.radiance, batch.owner, loaded)
                    pending = queued
            except BaseException:
                for future in pending + queued:
                    future.cancel()
                raise
        if bad_values:
            raise DatasetError(f"{first_bad}: NaN or Inf radiance ({bad_values} values in {bad_frames} frame(s); "
                               "this is the first)")
        slots_to_offsets(responses, self.slot_of)
        unobserved = ~self.observed[row0:row1]
        responses[unobserved] = 0.0
        steady[unobserved] = np.nan
        beyond = np.abs(steady) > np.finfo(np.float32).max  # NaN compares False
        if beyond.any():  # float32 would hold -inf (numpy's "overflow encountered in cast", exit 0)
            y, x, channel = np.argwhere(beyond)[0]
            dark = f" (dark frame {self.manifest.dark})" if self.manifest.dark is not None else ""
            raise DatasetError(f"{self.manifest.folder}: the steady state (the sum of all frames) at grid point "
                               f"[{row0 + y}, {x}] is {steady[y, x, channel]:.3g}, beyond float32's range: check the "
                               f"frames' values, exposures and dark frame{dark}")
        return responses, steady.astype(np.float32)

    def _load_group(self, batch: _Batch, slot: int, start: int, stop: int, row0: int, row1: int,
                    decoded: tuple[np.ndarray, int] | None = None) -> list[int]:
        """Frames ``start .. stop`` into ``batch`` from ``slot`` on (the first from ``decoded`` when
        given), the library silenced once for all of them; their counts of NaN or Inf values.
        Runs of small frames decode in one compiled call (:class:`.frame_batch.BatchDecoder`), the
        others (and any frame it hands back) one by one (:meth:`_load`), in order: the first frame
        at fault is the one named."""
        bad: list[int] = []
        arguments = (self.dy, self.dx, self.offset_index, self.inverse_counts)
        with quiet_library():
            if decoded is not None:
                bad.append(self._load(batch, slot, start, row0, row1, decoded))
            while start + len(bad) < stop:
                index = start + len(bad)
                at = slot + len(bad)
                if not self.batches.usable:
                    bad.append(self._load(batch, at, index, row0, row1))
                    continue
                run, status, counts = self.batches.load(index, stop, row0, row1, batch.radiance, batch.owner, at,
                                                        arguments)
                self.identities[index:index + len(run)] = run.identities
                if not status.any():
                    bad += counts.tolist()
                else:
                    for offset, (state, count) in enumerate(zip(status.tolist(), counts.tolist())):
                        if offset in run.errors:  # could not be opened: the first frame at fault so far
                            raise run.errors[offset]
                        if state == READ_ALONE:
                            count = self._load(batch, at + offset, index + offset, row0, row1)
                        elif state:
                            raise self.reader.scaling_error(self.manifest.frames[index + offset], state)
                        bad.append(count)
        return bad

    def _load(self, batch: _Batch, slot: int, index: int, row0: int, row1: int,
              decoded: tuple[np.ndarray, int] | None = None) -> int:
        """Decode frame ``index``'s rows ``row0 .. row1`` (unless ``decoded`` holds what
        :meth:`.FrameReader.read` gave) into ``batch`` at ``slot``, mark which offset each point
        takes from it and weigh the point's radiance; returns its count of NaN or Inf values."""
        frame = self.manifest.frames[index]
        if decoded is not None:
            batch.radiance[slot], bad = decoded
        else:
            _, bad = self.reader.read(frame, (row0, row1), batch.radiance[slot], self.identities[index])
        batch.owner[slot] = -1
        owners(batch.owner[slot], batch.radiance[slot], frame.lit, self.dy, self.dx, self.offset_index,
               self.inverse_counts, row0)
        return bad


class _Batch:
    """Frames' rows waiting to be scattered: (B, rows, W, 3) float32 radiance, already weighed (by
    1 / frames lighting the lit point it comes from), and (B, rows, W) owner: the slot of the offset
    each point takes, -1 for none; int16 while the slots fit in it (a disc of radius 102 or less).
    The scatter reads every frame's batch again, so its size is its speed: 14 bytes a point where an
    int32 owner and a float32 weight made 20 took the scatter of the 256 px benchmark's frames from
    1.82-1.99 s to 1.34 s on one thread (alternated runs)."""

    def __init__(self, size: int, rows: int, width: int, offsets: int):
        self.radiance = np.empty((size, rows, width, 3), np.float32)
        self.owner = np.empty((size, rows, width), _owner_type(offsets))

    @staticmethod
    def point_bytes(offsets: int) -> int:
        """Bytes a batch takes per point of a frame's rows."""
        return 12 + np.dtype(_owner_type(offsets)).itemsize


def _owner_type(offsets: int) -> type:
    return np.int16 if offsets <= np.iinfo(np.int16).max else np.int32


def assemble_in_memory(assembler: Assembler, budget: int, progress: ProgressCallback | None = None,
                       share: float = 1.0) -> Assembled:
    """The whole response array at once (its batches within an eighth of ``budget``);
    ``progress`` goes from 0 to ``share``."""
    report = None if progress is None else (lambda fraction: progress(share * fraction))
    phase("reading the frames")
    responses, steady = assembler.band(0, assembler.height, report, min(BATCH_BYTES, budget // 8))
    return Assembled(responses, assembler.lit_counts, assembler.observed, steady)


def write_assembled(writer: StoreWriter, assembled: Assembled, progress: ProgressCallback | None = None,
                    start: float = 0.0) -> None:
    """Write an in-memory assembly into a store, tile row by tile row; progress from ``start`` to 1."""
    height = assembled.responses.shape[0]
    phase("writing the store")
    for row in range(0, height, writer.tile):
        writer.write_rows(row, assembled.responses[row:row + writer.tile])
        if progress is not None:
            progress(start + (1.0 - start) * min(row + writer.tile, height) / height)
    writer.write_small(assembled.lit_counts, assembled.observed, assembled.steady)


BAND_SHARE = 0.5
"""Share of the memory budget one band of an out-of-core build takes; its batches of frames take
at most an eighth, and writing it a few chunks' copies."""


def assemble_into_store(assembler: Assembler, writer: StoreWriter, budget: int,
                        progress: ProgressCallback | None = None,
                        preview: Callable[[int, int, np.ndarray], None] | None = None) -> None:
    """Build the store band by band, each band a whole number of tiles within :data:`BAND_SHARE`
    of ``budget``; ``preview(row0, row1, steady rows)`` after each band is written."""
    row_bytes = assembler.width * len(assembler.offsets) * 12
    rows = max(writer.tile, (int(budget * BAND_SHARE) // max(row_bytes, 1)) // writer.tile * writer.tile)
    height = assembler.height
    steady = np.empty((height, assembler.width, 3), np.float32)
    bands = -(-height // rows)
    for row0 in range(0, height, rows):
        row1 = min(row0 + rows, height)
        report = None if progress is None else (
            lambda fraction, row0=row0, row1=row1: progress((row0 + fraction * (row1 - row0)) / height))
        phase(f"band {row0 // rows + 1} of {bands}: reading the frames")
        band, steady[row0:row1] = assembler.band(row0, row1, report, min(BATCH_BYTES, budget // 8))
        phase(f"band {row0 // rows + 1} of {bands}: writing the store")
        writer.write_rows(row0, band)
        del band
        if preview is not None:
            preview(row0, row1, steady[row0:row1].copy())
    writer.write_small(assembler.lit_counts, assembler.observed, steady)


@contextmanager
def _decoding_threads(count: int) -> Iterator[None]:
    """OpenEXR's own threads while a band is read: none for frames its reader of whole files
    decodes, which the reader threads decode side by side without the GIL (256 px frames: 1.5 s
    wall for 2401 where two threads inside each frame took 2.3 s), one a core otherwise, for the
    library's selecting reader, which decodes holding the GIL (its Python binding has the setting
    from 3.5 on; older ones decode on one)."""
    if not hasattr(OpenEXR, "set_global_thread_count"):
        yield
        return
    before = OpenEXR.global_thread_count()
    OpenEXR.set_global_thread_count(count)
    try:
        yield
    finally:
        OpenEXR.set_global_thread_count(before)
