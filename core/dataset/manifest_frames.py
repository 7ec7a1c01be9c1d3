"""The ``frames`` of a dataset manifest (docs/format/dataset.md): each frame's file, lit points,
exposure and replicate checked as the JSON decodes and gathered in one :class:`.frame_table.FrameTable`,
and no lit point listed twice by frames of one replicate. Part of :func:`.manifest.parse_manifest`:
problems raise through its :class:`~ringlight.core.validation.Validator`, naming the manifest and
the frame."""

from __future__ import annotations

import numpy as np

from ..errors import DatasetError
from ..validation import Validator, short_repr
from .frame_table import FLOAT32_MAX, FLOAT32_TINY, FRAME_KEYS, MAX_REPLICATE, Collected, FrameTable
from .spacing import POINTS_AT_ONCE

_FRAME_KEYS = set(FRAME_KEYS)


def parse_frames(check: Validator, entries: list, height: int, width: int) -> FrameTable:
    """Validate the ``frames`` list into a :class:`FrameTable`.

    The frames :class:`FrameCollector` took while the JSON was decoded are rows already (exact
    types, checked one by one as they were decoded); any other element is checked here, in order,
    through :class:`Validator`, which raises the precise message. Then the lit points of all frames
    are checked together with numpy: a 100,000-frame manifest validates in well under a second.
    """
    collector = next((entry.collector for entry in entries if type(entry) is Collected), None)
    if collector is not None and len(collector.files) == len(entries):  # every frame taken: the usual case
        table = collector.table()
        lit, points = table.lit, None
    else:
        files, exposures, counts, points, replicates = [], [], [], [], []
        taken = 0
        for index, entry in enumerate(entries):
            if type(entry) is Collected:
                file, lit, exposure, replicate = collector.row(taken)
                taken += 1
            else:
                file, lit, exposure, replicate = _checked_frame(check, index, entry)
            replicates.append(replicate)
            files.append(file)
            exposures.append(exposure)
            counts.append(len(lit))
            points.extend(lit)
        if not files:
            return FrameTable([], [], [], [], np.zeros((0, 2), np.int64))
        try:
            lit = np.array(points, np.int64).reshape(-1, 2)
        except OverflowError:  # an integer beyond int64 is outside any grid
            lit = None
        table = None if lit is None else FrameTable(files, exposures, replicates, counts, lit)
    if table is not None and not len(table):
        return table
    if lit is not None:
        outside = (lit[:, 0] < 0) | (lit[:, 0] >= height) | (lit[:, 1] < 0) | (lit[:, 1] >= width)
        first_outside = int(np.argmax(outside)) if outside.any() else None
    else:
        first_outside = next(i for i, (y, x) in enumerate(points) if not (0 <= y < height and 0 <= x < width))
    if first_outside is not None:
        ends = np.cumsum(table.counts if table is not None else counts)
        index = int(np.searchsorted(ends, first_outside, side="right"))
        y, x = (lit[first_outside].tolist() if lit is not None else points[first_outside])
        name = table.files[index] if table is not None else files[index]
        raise DatasetError(f"{check.where}: frames[{index}] ({name}) lights "
                           f"[{short_repr(y)}, {short_repr(x)}], outside the {height} x {width} grid")
    multiple = np.flatnonzero(table.counts > 1)
    if len(multiple):
        _check_no_point_twice(check, table, multiple, height * width, width)
    return table


def _check_no_point_twice(check: Validator, table: FrameTable, multiple: np.ndarray, points: int,
                          width: int) -> None:
    """DatasetError naming the first of the frames ``multiple`` (indices of frames lighting
    several points) that lists a lit point twice; checked a run of frames of at most
    :data:`POINTS_AT_ONCE` points at a time (one frame at least)."""
    ends = table.starts[multiple + 1]
    at = 0
    while at < len(multiple):
        stop = max(at + 1, int(np.searchsorted(ends, table.starts[multiple[at]] + POINTS_AT_ONCE, side="right")))
        frames = multiple[at:stop]
        lengths = table.counts[frames]
        rows = np.arange(int(lengths.sum())) + np.repeat(table.starts[frames] - (np.cumsum(lengths) - lengths), lengths)
        # Python ints bound the key: frames * H * W < 2**63 for any manifest under the size limit.
        keys = np.repeat(frames.astype(np.int64) * points, table.counts[frames])
        keys += table.lit[rows, 0] * width + table.lit[rows, 1]
        keys.sort()
        if (keys[1:] == keys[:-1]).any():
            index = int(frames[np.searchsorted(frames * points, keys[np.flatnonzero(keys[1:] == keys[:-1])[0]],
                                               side="right") - 1])
            raise DatasetError(f"{check.where}: frames[{index}] ({table.files[index]}) lists a lit point twice")
        at = stop


def _checked_frame(check: Validator, index: int, entry: object) -> tuple[str, list, float, int]:
    """``(file, lit points, exposure, replicate)`` of a frame the collector did not take, or
    DatasetError saying what is wrong with it."""
    if type(entry) is not dict or not entry.keys() <= _FRAME_KEYS or "file" not in entry or "lit" not in entry:
        check.mapping(entry, f"frames[{index}]", _FRAME_KEYS, required={"file", "lit"})
    file = check.relative_file(entry["file"], f"frames[{index}].file")
    lit = entry["lit"]
    if type(lit) is not list or not lit or not all(
            type(point) is list and len(point) == 2 and type(point[0]) is int and type(point[1]) is int
            for point in lit):
        _raise_bad_lit(check, index, file, lit)
    exposure = entry.get("exposure", 1.0)
    if type(exposure) is not float or not FLOAT32_TINY <= exposure <= FLOAT32_MAX:
        exposure = _checked_exposure(check, index, exposure)
    replicate = entry.get("replicate", 0)
    if type(replicate) is not int or not 0 <= replicate <= MAX_REPLICATE:
        raise check.fail(f"frames[{index}].replicate", f"a whole number in [0, {MAX_REPLICATE}]", replicate)
    return file, lit, exposure, replicate


def _raise_bad_lit(check: Validator, index: int, file: str, lit: object) -> None:
    name = f"frames[{index}].lit"
    points = check.sequence(lit, name)
    if not points:
        raise DatasetError(f"{check.where}: frames[{index}] ({file}) lights no point")
    at, bad = next((at, point) for at, point in enumerate(points) if not (
        type(point) is list and len(point) == 2 and type(point[0]) is int and type(point[1]) is int))
    raise DatasetError(f"{check.where}: {name}[{at}] must be [y, x] integers, got {short_repr(bad)}")


def _checked_exposure(check: Validator, index: int, value: object) -> float:
    exposure = check.positive_number(value, f"frames[{index}].exposure")
    if not FLOAT32_TINY <= exposure <= FLOAT32_MAX:
        raise DatasetError(f"{check.where}: frames[{index}].exposure {exposure:g} cannot be represented in "
                           f"float32 (it must lie in [{FLOAT32_TINY:.3g}, {FLOAT32_MAX:.3g}])")
    return exposure
