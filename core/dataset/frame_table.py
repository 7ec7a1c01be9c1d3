"""A manifest's frames as one table of arrays, and the reading of its ``frames`` key into it.

A frame of a long manifest was a Python object with its own lit-point array (about 300 bytes a
frame beside the JSON's 60), and the decoded JSON of every frame (a dict, lists of lists: about
130 bytes a lit point) was held until all were validated: a million frames took 1.3 GB, 7.2
million lit points 1.7 GB. :class:`FrameCollector` turns each element of the ``frames`` array
into a row of compact arrays as soon as the JSON decoder has made it
(:func:`ringlight.core.validation.decode_json`'s element hooks), so that only one frame's JSON
objects exist at a time; :class:`FrameTable` keeps the rows (files, exposures, replicates, how
many points each lights, and all lit points in one (P, 2) int64 array) and gives
:class:`FrameEntry` views of single frames to code that walks them.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from itertools import chain

import numpy as np

_LIST, _PAIR, _INT = {list}, {2}, {int}
FRAME_KEYS = frozenset({"file", "lit", "exposure", "replicate"})
MAX_REPLICATE = 2**31 - 1
FLOAT32_TINY = float(np.finfo(np.float32).tiny)
FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True, eq=False)
class FrameEntry:
    """One captured frame: its file (relative to the dataset folder), lit points and exposure.

    ``lit`` is an (n, 2) int64 array of grid positions ``[y, x]``. ``replicate`` labels the
    independent repeat of the capture the frame belongs to (the manifest's optional frame key;
    0 when absent): see :attr:`.manifest.Manifest.replicates`.
    """

    file: str
    lit: np.ndarray
    exposure: float
    replicate: int = 0


class FrameTable(Sequence):
    """The frames of a manifest: a sequence of :class:`FrameEntry`, made on access.

    Attributes
    ----------
    files
        Each frame's file name (list of str).
    exposures
        (F,) float64 relative exposures.
    replicates
        (F,) int64 replicate labels.
    counts
        (F,) int64 number of points each frame lights (at least 1).
    lit
        (P, 2) int64 lit points ``[y, x]`` of all frames, frame after frame.
    starts
        (F + 1,) int64: frame ``i`` lights ``lit[starts[i]:starts[i + 1]]``.
    """

    def __init__(self, files: list[str], exposures: np.ndarray, replicates: np.ndarray, counts: np.ndarray,
                 lit: np.ndarray):
        self.files = files
        self.exposures = np.asarray(exposures, np.float64)
        self.replicates = np.asarray(replicates, np.int64)
        self.counts = np.asarray(counts, np.int64)
        self.lit = np.asarray(lit, np.int64).reshape(-1, 2)
        self.starts = np.zeros(len(files) + 1, np.int64)
        np.cumsum(self.counts, out=self.starts[1:])

    @classmethod
    def from_entries(cls, entries) -> FrameTable:
        """The table of a sequence of :class:`FrameEntry` (a manifest built in memory)."""
        if isinstance(entries, FrameTable):
            return entries
        entries = tuple(entries)
        lit = (np.concatenate([np.asarray(entry.lit, np.int64).reshape(-1, 2) for entry in entries])
               if entries else np.zeros((0, 2), np.int64))
        return cls([entry.file for entry in entries], [entry.exposure for entry in entries],
                   [entry.replicate for entry in entries], [len(entry.lit) for entry in entries], lit)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return tuple(self._entry(at) for at in range(*index.indices(len(self))))
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError("frame index out of range")
        return self._entry(index)

    def __iter__(self) -> Iterator[FrameEntry]:
        for index in range(len(self)):
            yield self._entry(index)

    def _entry(self, index: int) -> FrameEntry:
        return FrameEntry(self.files[index], self.lit[self.starts[index]:self.starts[index + 1]],
                          float(self.exposures[index]), int(self.replicates[index]))

    def frame_of_point(self) -> np.ndarray:
        """(P,) int64: the frame each row of :attr:`lit` belongs to."""
        return np.repeat(np.arange(len(self), dtype=np.int64), self.counts)

    def __repr__(self) -> str:
        return f"FrameTable({len(self)} frames, {len(self.lit)} lit points)"


class Collected:
    """What :class:`FrameCollector` leaves in the decoded ``frames`` list in place of a frame it
    took: one object for all of them (their order is the rows' order)."""

    __slots__ = ("collector",)

    def __init__(self, collector: FrameCollector):
        self.collector = collector

    def __repr__(self) -> str:
        return "{...}"


class FrameCollector:
    """Called with each decoded element of one ``frames`` array: a frame whose keys and values
    have exactly the expected types (file a plain relative name, lit points ``[y, x]`` of int64,
    exposure in float32's range, replicate in range) becomes a row of its arrays and is replaced
    by :attr:`marker`; anything else is returned as it is, for the manifest's validation to
    report in order (:func:`.manifest.parse_manifest`)."""

    def __init__(self) -> None:
        self.marker = Collected(self)
        self.files: list[str] = []
        self.exposures = array("d")
        self.replicates = array("q")
        self.counts = array("q")
        self.points = array("q")
        self._ends: np.ndarray | None = None

    def __call__(self, entry: object) -> object:
        if type(entry) is not dict or not entry.keys() <= FRAME_KEYS:
            return entry
        file, lit = entry.get("file"), entry.get("lit")
        if type(file) is not str or type(lit) is not list or not lit or not _plain_name(file):
            return entry
        exposure = entry.get("exposure", 1.0)
        if type(exposure) is int:
            exposure = float(exposure) if abs(exposure) < 2**64 else None
        if type(exposure) is not float or not FLOAT32_TINY <= exposure <= FLOAT32_MAX:
            return entry
        replicate = entry.get("replicate", 0)
        if type(replicate) is not int or not 0 <= replicate <= MAX_REPLICATE:
            return entry
        if len(lit) == 1:
            point = lit[0]
            if type(point) is not list or len(point) != 2 or type(point[0]) is not int or type(point[1]) is not int:
                return entry
            flat = point
        else:  # the types of a multiplexed frame's points tested by C loops, not a Python loop a point
            if set(map(type, lit)) != _LIST or set(map(len, lit)) != _PAIR:
                return entry
            flat = list(chain.from_iterable(lit))
            if set(map(type, flat)) != _INT:
                return entry
        try:
            points = array("q", flat)
        except OverflowError:  # beyond int64: outside any grid, said by the validation
            return entry
        self.points += points
        self.files.append(file)
        self.exposures.append(exposure)
        self.replicates.append(replicate)
        self.counts.append(len(lit))
        return self.marker

    def row(self, row: int) -> tuple[str, list, float, int]:
        """``(file, lit points as [y, x] lists, exposure, replicate)`` of a row taken (for a
        ``frames`` list in which some elements were not taken; they are then all checked in
        order)."""
        if self._ends is None or len(self._ends) != len(self.counts):
            self._ends = np.cumsum(np.frombuffer(self.counts, np.int64)) if self.counts else np.zeros(0, np.int64)
        stop = int(self._ends[row])
        start = stop - self.counts[row]
        flat = self.points[2 * start:2 * stop].tolist()
        return (self.files[row], [flat[at:at + 2] for at in range(0, len(flat), 2)], self.exposures[row],
                self.replicates[row])

    def table(self) -> FrameTable:
        return FrameTable(self.files, np.frombuffer(self.exposures, np.float64) if self.exposures else [],
                          np.frombuffer(self.replicates, np.int64) if self.replicates else [],
                          np.frombuffer(self.counts, np.int64) if self.counts else [],
                          np.frombuffer(self.points, np.int64) if self.points else np.zeros((0, 2), np.int64))


def _plain_name(name: str) -> bool:
    """Whether ``name`` passes :meth:`ringlight.core.validation.Validator.relative_file` by the
    cheapest tests (ASCII, short, no odd character); other names take the validator's own."""
    return (0 < len(name) <= 255 and name.isascii() and name[0] != "/" and "\\" not in name and "\0" not in name
            and ".." not in name)
