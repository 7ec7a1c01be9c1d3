"""Checking every file a dataset references, cheaply, without decoding any pixels.

``ringlight info`` reports what :func:`check_files` finds, so that a truncated or missing frame is
known before a long open or stack, not halfway through one.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from ..errors import DatasetError
from .exr import visit_exr
from .exr_chunks import chunk_tables_fit
from .exr_seen import HeaderCache, PassedHeader
from .exr_header import RGB, quiet_library
from .file_batch import FileRun, read_run, reader_count
from .file_paths import FileResolver
from .frames import dataset_channels
from .manifest import Manifest


RUN_FILES = 1024
"""Frames read in one run (:func:`.file_batch.read_run`): at most 64 MiB of small files' bytes."""
MOST_READERS = 4
"""Most threads reading runs at once (:func:`_checked_runs`): each run read ahead is held, so a
check holds at most five runs' bytes (a run of 1024 10 x 10 frames is about 0.4 MB, of 1024
files of 64 KiB, the most read whole, 64 MiB)."""


def check_files(manifest: Manifest, allow_outside: bool = False,
                progress: Callable[[float], None] | None = None) -> list[str]:
    """Check the header of every file ``manifest`` references, in manifest order; one line per
    problem (see :func:`find_file_problems`)."""
    return find_file_problems(manifest, allow_outside, progress)[0]


def find_file_problems(manifest: Manifest, allow_outside: bool = False,
                       progress: Callable[[float], None] | None = None,
                       keep: int | None = None) -> tuple[list[str], int]:
    """Check the header of every file ``manifest`` references, in manifest order.

    Each file is checked as reading it would check it (see
    :func:`ringlight.core.dataset.exr.check_exr`): it resolves inside the dataset folder (unless
    ``allow_outside``), is a regular OpenEXR file, has the channels it needs (the manifest's
    ``channels``, else R, G, B or a lone Y; ``y`` and ``x`` for the mapping) at full resolution, in the manifest's ``part``, with chromaticities that
    match its ``colorspace`` and a data window that is its display window, has the size it must
    have (frames and dark: the grid, or the mapping's size in camera frame space; ground-truth
    images: the grid), and its chunk table fits the file (a truncated file fails this).

    Parameters
    ----------
    manifest
        A validated manifest.
    allow_outside
        Accept files that resolve outside the dataset folder through symbolic links.
    progress
        Called with the fraction of files checked, in [0, 1].
    keep
        Lines kept (None: all): a manifest of a million missing frames makes a million lines,
        of which a report shows a few.

    Returns
    -------
    The first ``keep`` lines, one per problem, each naming its file (empty when every file
    passes), and how many problems there are.

    Notes
    -----
    Each file is opened once; the library reads a header only when it differs from those already
    checked (:mod:`.exr_seen`), and every folder on the way is resolved once
    (:class:`.file_paths.FileResolver`). Frames are read in runs (:func:`.file_batch.read_run`):
    those that share the first good frame's header and are small have their chunk tables checked
    in one compiled call a run (:func:`.exr_chunks.chunk_tables_fit`); any other frame, and one
    whose table does not fit, is checked alone (:func:`.exr.visit_exr`), which says what is wrong.
    The work a frame is a few system calls.
    """
    problems: list[str] = []
    total = 0
    resolver = FileResolver(manifest.folder, allow_outside)
    headers = HeaderCache()

    def problem(error: DatasetError) -> None:
        nonlocal total
        total += 1
        if keep is None or len(problems) < keep:
            problems.append(str(error))

    def check(name: str, channels: tuple[str, ...], shape, what: str, size_of: str | None,
              frame=True) -> tuple[PassedHeader | None, tuple[int, int]] | None:
        """Check one file: its header's entry in ``headers`` and its size, or None when it failed."""
        try:
            descriptor, path, _ = resolver.open(name)
            header, _, passed = visit_exr(path, channels, shape, what, size_of, manifest.part if frame else None,
                                          manifest.colorspace if frame else None, headers, descriptor=descriptor)
        except DatasetError as error:
            problem(error)
            return None
        return passed, (header.height, header.width)

    frame_shape, size_of = (manifest.height, manifest.width), "the grid"
    if manifest.frame_space == "camera":
        # A broken mapping leaves the frames' size unknown: they are then checked for all else.
        checked = check(manifest.mapping, ("y", "x"), None, "mapping", None, frame=False)
        frame_shape, size_of = checked[1] if checked else None, "the mapping"
    try:
        channels = dataset_channels(manifest, allow_outside)
    except DatasetError:  # the first frame's own problem is reported below
        channels = manifest.channels or RGB
    if manifest.dark is not None:
        check(manifest.dark, channels, frame_shape, "dark frame", size_of)
    truth = manifest.ground_truth.path_length_images if manifest.ground_truth else ()
    files = len(manifest.frames) + len(truth)
    names = manifest.frames.files
    done, shared = 0, None
    with quiet_library():  # silenced once for all frames, not redirected and restored once a frame
        while done < len(names):
            if shared is None:  # frames one by one until one passes: its header is the one shared
                checked = check(names[done], channels, frame_shape, "frame", size_of)
                passed = checked[0] if checked else None
                if passed is not None and not passed.layout.tiled \
                        and passed.layout.first == passed.layout.entries:
                    shared = passed
                done += 1
            else:
                for run, fits in _checked_runs(resolver, names, done, shared):
                    for at in np.flatnonzero(~fits).tolist():  # checked alone, in order: its problem said as ever
                        if at in run.errors:
                            problem(run.errors[at])
                        else:
                            check(names[done + at], channels, frame_shape, "frame", size_of)
                    done += len(run)
                    if progress is not None:
                        progress(done / files)
                continue
            if progress is not None:
                progress(done / files)
    for image in truth:
        check(image.file, RGB, (manifest.height, manifest.width), "ground-truth image", "the grid", frame=False)
    if progress is not None:
        progress(1.0)
    return problems, total


def _checked_runs(resolver: FileResolver, names, start: int,
                  shared: PassedHeader) -> Iterator[tuple[FileRun, np.ndarray]]:
    """The frames ``names[start:]`` in runs of :data:`RUN_FILES`, in order: each run read
    (:func:`.file_batch.read_run`, with the header of ``shared``) and whether each of its frames'
    chunk table fits its file ((n,) bool). Runs are read by :func:`.file_batch.reader_count`
    threads (at most :data:`MOST_READERS`): the compiled calls that visit the files and check the
    tables release the GIL, so the runs' system calls share the cores. At most one run a thread is
    read ahead of the one the caller has."""
    def read(at: int) -> tuple[FileRun, np.ndarray]:
        run = read_run(resolver, names[at:at + RUN_FILES], shared.header_bytes)
        fits = np.zeros(len(run), np.bool_)
        chunk_tables_fit(run.data, run.starts, run.sizes, shared.layout.table_start, shared.layout.first, fits)
        return run, fits

    readers = min(reader_count(), MOST_READERS)
    with ThreadPoolExecutor(max_workers=readers) as pool:
        pending: deque[Future] = deque()
        try:
            for at in range(start, len(names), RUN_FILES):
                pending.append(pool.submit(read, at))
                if len(pending) > readers:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:  # the caller stopped (an error): runs not started are not read
            for future in pending:
                future.cancel()
