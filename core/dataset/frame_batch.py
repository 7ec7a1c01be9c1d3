"""A run of small frames decoded, weighed and marked for the scatter in one compiled call.

Frame by frame, a 10 x 10 frame cost about 35 us of Python around a few microseconds of work: its
opening and check, the decode's chunk walk, three compiled calls (decode, radiance, owners), each
with its fixed cost. Here a run of frames that share the header of the dataset's first frame and
are small enough (:mod:`.exr_small`) is read into one buffer (:func:`.file_batch.read_run`: a few
system calls a frame) and then, in one compiled call, each frame's chunk table is checked, its
chunks inflated and unpacked, its radiance made (``frame / exposure - dark``, as
:meth:`.frames.FrameReader.read`) and the offset each point takes from it marked and weighed
(:func:`owners`). A frame this cannot take (another header, a chunk table that does not fit, data
zlib refuses, a value out of float32's range) is handed back to be read alone, as before, which
says what is wrong in the same words.
"""

from __future__ import annotations

import numba
import numpy as np

from .exr_seen import PassedHeader
from .exr_small import _HALF_TO_FLOAT, LENGTH_TYPE, NATIVE_INFLATE, _decode_frame, _picked, layout_array
from .file_batch import FileRun, read_run
from .frames import FrameReader, _radiance

READ_ALONE = 3
"""Status of a frame to read alone (:meth:`BatchDecoder.load`); 0 is decoded, 1 and 2 the
problems of :func:`.frames._radiance` (dividing, subtracting the dark frame)."""


class BatchDecoder:
    """Loads runs of a dataset's grid-space frames into a batch of the assembly (see the module
    docstring); :attr:`usable` is False when none can be (camera frames, which are mapped; a first
    frame of another layout; no zlib to call), and frames are then read one by one."""

    def __init__(self, reader: FrameReader, passed: PassedHeader | None):
        self.reader = reader
        self.passed = passed
        small = passed.small if passed is not None else None
        picked = _picked(small, reader.channels) if small is not None else None
        self.usable = (NATIVE_INFLATE and reader.mapping is None and picked is not None
                       and not passed.layout.tiled
                       and passed.layout.first == passed.layout.entries == -(-small.height // small.lines))
        self.picked = picked

    def load(self, start: int, stop: int, row0: int, row1: int, radiance: np.ndarray, owner: np.ndarray,
             slot: int, owner_arguments: tuple) -> tuple[FileRun, np.ndarray, np.ndarray]:
        """Load frames ``start .. stop`` (rows ``row0 .. row1``) into ``radiance`` and ``owner`` ((B,
        rows, W, 3) and (B, rows, W), the assembly's batch) from index ``slot`` on.

        ``owner_arguments``: ``(dy, dx, offset_index, inverse_counts)`` of :func:`owners`. Returns the
        run read (with the errors of frames that could not be opened), and for each frame of it its
        status (0, 1, 2 or :data:`READ_ALONE`) and its count of NaN or Inf values."""
        frames, reader = self.reader.manifest.frames, self.reader
        run = read_run(reader.resolver, frames.files[start:stop], self.passed.header_bytes)
        count = len(run)
        status = np.zeros(count, np.int64)
        bad = np.zeros(count, np.int64)
        if count == 0:
            return run, status, bad
        small = self.passed.small
        image = np.empty((row1 - row0, small.width, len(reader.channels)), np.float32)
        dark = (reader.dark[row0:row1] if reader.dark is not None
                else np.zeros((0, 0, len(reader.channels)), np.float32))
        _load_frames(run.data, run.starts, run.sizes, layout_array(small, self.passed.layout.table_start, row0),
                     small.width, *self.picked, _HALF_TO_FLOAT, image, np.zeros(2, LENGTH_TYPE),
                     frames.exposures[start:start + count].astype(np.float32), dark, reader.dark is not None,
                     radiance, owner, slot, frames.lit, frames.starts[start:start + count + 1], *owner_arguments, row0,
                     status, bad)
        return run, status, bad


@numba.njit(cache=True, nogil=True)
def _load_frames(data, starts, sizes, layout, width, channel_starts, halves, targets, half_to_float, image, lengths,
                 exposures, dark, has_dark, radiance, owner, slot, lit, lit_starts, dy, dx, offset_index,
                 inverse_counts, row0, status, bad):  # pragma: no cover - compiled
    """Frame ``b`` of the run (bytes ``data[starts[b]:starts[b] + sizes[b]]``, size -1: not read)
    decoded into ``image``, its radiance into ``radiance[slot + b]`` and its owners into
    ``owner[slot + b]``; ``status[b]`` and ``bad[b]`` as :meth:`BatchDecoder.load` returns them.
    (Numba caches this with its callees from other modules compiled in: after editing
    :func:`.exr_small._decode_frame` or :func:`.frames._radiance`, clear ``__pycache__``.)"""
    raw = np.empty(layout[2] * layout[5], np.uint8)  # a chunk's bytes (lines x line bytes)
    for b in range(sizes.size):
        if sizes[b] < 0 or not _decode_frame(data, starts[b], sizes[b], layout, width, channel_starts, halves,
                                             targets, half_to_float, image, lengths, raw):
            status[b] = READ_ALONE
            continue
        out = radiance[slot + b]
        bad[b], status[b] = _radiance(image, exposures[b], dark, has_dark, out)
        if status[b]:
            continue
        marks = owner[slot + b]
        marks[:] = -1
        owners(marks, out, lit[lit_starts[b]:lit_starts[b + 1]], dy, dx, offset_index, inverse_counts, row0)


@numba.njit(cache=True, nogil=True)
def owners(owner, radiance, lit, dy, dx, offset_index, inverse_counts, row0):  # pragma: no cover - compiled
    """For each point p of the band (rows row0 ..) within reach of a lit point q of a frame:
    ``owner[p - row0]`` = the slot ``offset_index[j]`` of d = q - p = (dy[j], dx[j]), and
    ``radiance[p - row0]`` (3,) float32 weighed by 1 / (frames lighting q); other points keep
    ``owner`` -1. One q per p:
    multiplexed points are more than ``2 max_radius`` apart (checked with the manifest), and other
    frames light one point."""
    rows, width = owner.shape
    reach = 0
    for j in range(dy.size):
        reach = max(reach, abs(dy[j]))
    for i in range(lit.shape[0]):
        qy = lit[i, 0]
        qx = lit[i, 1]
        if qy + reach < row0 or qy - reach >= row0 + rows:
            continue  # no point of the band within reach
        for j in range(dy.size):
            py = qy - dy[j] - row0
            px = qx - dx[j]
            if py >= 0 and py < rows and px >= 0 and px < width:
                owner[py, px] = offset_index[j]
                weight = inverse_counts[qy, qx]
                for c in range(3):
                    radiance[py, px, c] *= weight
