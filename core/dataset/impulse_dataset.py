"""Opening impulse datasets (format version 1, docs/format/dataset.md) into a compact in-memory response model.

The model never forms the dense N x N light transport. For each grid point ``p`` it keeps the
radiance seen at ``p`` from every lit point within ``max_radius`` of it:

    responses[y, x, k, c] = I_q(p)[c]  with  p = [y, x],  q = p + offsets[k],

where ``offsets`` are all integer offsets with ``|d| <= max_radius`` (:func:`.disc.disc_offsets`).
Invariant: entries whose ``q`` lies outside the grid or is missing (lit in no frame), and all
entries of unobserved ``p``, hold exactly 0; ``lit_counts`` tells which ``q`` exist. Size:
``H * W * K * 3 * 4`` bytes with ``K ~ pi * max_radius**2``, e.g. 96 x 96 at max_radius 24
(K = 1789) is 198 MB, 800 x 800 is 13.8 GB.

Where it lives. A first open assembles the array (:mod:`.assembly`) and writes the dataset's
store (:mod:`.response_store`); an array that fits the memory budget (:mod:`.memory`) stays in
memory, a larger one is built band by band into the store. A reopen reads only the store's small
arrays (lit counts, observed points, the steady state) and reads responses band by band when
asked, keeping decoded bands up to the budget. Every consumer reads through :meth:`ImpulseDataset.rows`
(or :meth:`~ImpulseDataset.point`, :meth:`~ImpulseDataset.window`), so both work alike.

Long manifests. The work per frame is a few system calls and array rows: the manifest's frames are
one table of arrays, each frame made a row as its JSON is decoded (:mod:`.frame_table`). An open is
one pass over the files: a reopen stats each file for the store's key and opens none (the store
keeps the frames' channels); a first open
stats none (the dataset's store, if any, is of another manifest: :func:`.cache.manifest_key`) and
visits each frame file once, per band: opened inside the dataset folder, stat'ed, read whole in one
read when small and closed, a run of files in one compiled call (:mod:`.file_batch`,
:mod:`.native_files`), its ``fstat`` the identity the store's key is made of. Runs of small frames that share the first
frame's header are checked, decoded, weighed and marked in one compiled call a run
(:mod:`.frame_batch`); other frames are read one by one (:func:`.exr.visit_exr`, the header the
frames share read by the OpenEXR library once, :mod:`.exr_seen`). ``benchmarks/bench_manifest.py
--pipeline`` measures each step per frame against the parse.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from ..staging_locks import sweep_abandoned
from ..errors import DatasetError, ProgressCallback, RinglightError
from ..phases import phase
from . import cache
from .assembly import WRITE_SHARE, Assembler, assemble_in_memory, assemble_into_store, write_assembled
from .disc import disc_offsets, fill_validity, response_memory_bytes
from .frames import dataset_channels
from .manifest import Manifest, read_manifest
from .manifest_copy import load_manifest, write_manifest_copy
from .memory import format_bytes, memory_budget
from .response_store import ResponseStore, entry_bytes, open_store, store_tile, stored_manifest_key, write_store

SteadyPreview = Callable[[int, int, np.ndarray], None]
"""Called with the fraction of work done in [0, 1]; may raise :class:`Cancelled` to stop."""
WHOLE_READ_BYTES = 256 * 2**20
"""A reopened dataset whose responses are at most this big (and within the budget) is read whole
into memory; a larger one band by band as it is used, so that a reopen takes the same short time
at any size."""
IN_MEMORY_ROWS = 32
"""Rows a band of an in-memory dataset holds at least (enough work per thread, progress in steps)."""


@dataclass(frozen=True, eq=False)
class ImpulseDataset:
    """An opened impulse dataset: manifest plus the response model of the module docstring.

    Attributes
    ----------
    manifest
        The validated manifest.
    max_radius
        Radius (grid steps) up to which responses are kept: the manifest's ``max_radius``, or
        for one-point-per-frame datasets without one, the radius the opener asked for.
    offsets
        (K, 2) int64 offsets ``[dy, dx]`` of the response array's offset axis.
    responses
        (H, W, K, 3) float32 in memory, or None when the dataset is read from its store (see
        :attr:`in_memory` and :meth:`rows`).
    lit_counts
        (H, W) int32: frames in which each point was lit; 0 marks a missing point.
    observed
        (H, W) bool: grid points the frames show (camera datasets may miss some).
    channels
        The frame channels read: three (R, G, B) or one (a monochrome camera, whose responses
        hold its value in all three of R, G, B).
    store
        The store the responses are read from when ``responses`` is None.
    steady
        (H, W, 3) float32 steady state when known at open (a store holds it), else None.
    cache_key
        The key of the dataset's store (:func:`.cache.files_key`: its manifest, the identity of
        every frame file and the radius), which what is derived from the responses is cached
        under (:mod:`ringlight.core.rings.stack_cache`); empty when opened without the cache.
    """

    manifest: Manifest
    max_radius: float
    offsets: np.ndarray
    responses: np.ndarray | None
    lit_counts: np.ndarray
    observed: np.ndarray
    channels: tuple[str, ...] = ("R", "G", "B")
    store: ResponseStore | None = None
    steady: np.ndarray | None = None
    cache_key: str = ""

    @property
    def in_memory(self) -> bool:
        """True when the whole response array is in memory (else it is read band by band)."""
        return self.responses is not None

    @property
    def response_shape(self) -> tuple[int, int, int, int]:
        return (*self.grid_shape, len(self.offsets), 3)

    @property
    def band_height(self) -> int:
        """Rows of one band of :meth:`bands`: a store tile, or enough rows per compute call."""
        if self.store is not None and self.responses is None:
            return self.store.tile
        return max(IN_MEMORY_ROWS, -(-self.grid_shape[0] // 8))

    def bands(self) -> list[tuple[int, int]]:
        """``(row0, row1)`` of each band of rows, top to bottom."""
        height, rows = self.grid_shape[0], self.band_height
        return [(row, min(row + rows, height)) for row in range(0, height, rows)]

    def rows(self, row0: int, row1: int) -> np.ndarray:
        """Responses of grid rows ``row0 .. row1``: (rows, W, K, 3) float32, read-only (a view of
        the in-memory array, or the store's band or copy). Read-only whatever their source, so that
        each kernel that reads them is compiled for one type: numba compiled the stack's, the
        spread's and the interpolated rings' kernels once for writeable and once for read-only
        responses (3-5 s each on a fresh install)."""
        rows = self.responses[row0:row1] if self.responses is not None else self.store.rows(row0, row1)
        if rows.flags.writeable:
            rows = rows.view()
            rows.flags.writeable = False
        return rows

    def point(self, y: int, x: int) -> np.ndarray:
        """Responses at grid point ``p = [y, x]``: (K, 3) float32 (one store chunk read)."""
        return self.responses[y, x] if self.responses is not None else self.store.window(y, y + 1, x, x + 1)[0, 0]

    def window(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """Responses of a window of grid points: (rows, cols, K, 3) float32."""
        if self.responses is not None:
            return self.responses[row0:row1, col0:col1]
        return self.store.window(row0, row1, col0, col1)

    def validity_rows(self, row0: int, row1: int) -> np.ndarray:
        """(rows, W, K) uint8 validity flags of grid rows ``row0 .. row1``: 1 where
        ``responses[y, x, k]`` holds a real response (the lit point ``q = p + offsets[k]`` is
        inside the grid and not missing, and ``p`` is observed).

        Computed at each call from the lit and observed points, never kept: a band's flags are
        1/12 of its responses (a whole dataset's, once kept in memory, 110 MB at 256 x 256 and
        R 24), and a compiled pass makes them at a few GB/s."""
        validity = np.empty((row1 - row0, self.grid_shape[1], len(self.offsets)), np.uint8)
        fill_validity(self.lit, self.observed, self.offsets, validity, row0)
        return validity

    @property
    def monochrome(self) -> bool:
        """True for a monochrome camera's dataset (grey: R = G = B everywhere)."""
        return len(self.channels) == 1

    @property
    def path(self) -> Path:
        return self.manifest.folder

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (self.manifest.height, self.manifest.width)

    @property
    def colorspace(self) -> str:
        return self.manifest.colorspace

    @property
    def lit(self) -> np.ndarray:
        """(H, W) bool: points lit in at least one frame."""
        return self.lit_counts > 0

    @property
    def missing_count(self) -> int:
        """Number of grid points lit in no frame."""
        return int(np.count_nonzero(self.lit_counts == 0))

    def impulse_image(self, y: int, x: int) -> np.ndarray:
        """Impulse image of lit point ``q = [y, x]``: (H, W, 3) float32, NaN beyond max_radius,
        at unobserved points, and everywhere when ``q`` is missing."""
        height, width = self.grid_shape
        image = np.full((height, width, 3), np.nan, np.float32)
        if not self.lit_counts[y, x]:
            return image
        # I_q(p) is stored at p = q - d for offset index k of d.
        py = y - self.offsets[:, 0]
        px = x - self.offsets[:, 1]
        inside = (py >= 0) & (py < height) & (px >= 0) & (px < width)
        k = np.flatnonzero(inside)
        if len(k):
            row0, row1 = int(py[k].min()), int(py[k].max()) + 1
            col0, col1 = int(px[k].min()), int(px[k].max()) + 1
            window = self.window(row0, row1, col0, col1)
            image[py[k], px[k]] = window[py[k] - row0, px[k] - col0, k]
        image[~self.observed] = np.nan
        return image

    def steady_state(self) -> np.ndarray:
        """Appearance under full illumination of the grid: (H, W, 3) float32, the sum at each
        point of the responses of all lit points within max_radius; NaN where unobserved."""
        if self.steady is not None:
            return self.steady.copy()
        total = np.zeros((*self.grid_shape, 3), np.float64)
        for row0, row1 in self.bands():
            total[row0:row1] = self.rows(row0, row1).sum(axis=2, dtype=np.float64)
        total[~self.observed] = np.nan
        return total.astype(np.float32)


def effective_max_radius(manifest: Manifest, radius: float | None = None) -> float:
    """The max radius a dataset is opened at (see :func:`open_dataset`)."""
    if manifest.max_radius is not None:
        return manifest.max_radius
    if radius is not None:
        return float(radius)
    return math.hypot(manifest.height - 1, manifest.width - 1)


def open_dataset(
    path: str | Path | Manifest,
    *,
    radius: float | None = None,
    use_cache: bool = True,
    progress: ProgressCallback | None = None,
    memory_budget_bytes: int | None = None,
    allow_outside: bool = False,
    preview: SteadyPreview | None = None,
) -> ImpulseDataset:
    """Open an impulse dataset folder (or its ``dataset.json``).

    Parameters
    ----------
    path
        Dataset folder, its ``dataset.json``, or a :class:`Manifest` already read.
    radius
        For datasets without ``max_radius`` (one lit point per frame): the largest distance in
        grid steps any ring will reach; responses are kept up to it. Default: the grid diagonal.
        Ignored when the manifest sets ``max_radius``.
    use_cache
        Read and write the dataset's store (:mod:`.response_store`); without it the response
        array must fit the memory budget.
    progress
        Called with the fraction of the work done (reading frames, writing the store); may raise
        :class:`Cancelled`, which leaves no store behind.
    memory_budget_bytes
        Memory the open may fill (default :func:`.memory.memory_budget`): a larger response array
        is built band by band into the store and read from it.
    allow_outside
        Read frames, dark and mapping files that resolve (through symbolic links) outside the
        dataset folder; refused by default.
    preview
        Called as ``preview(row0, row1, steady)`` each time a band of an out-of-core build is
        assembled, ``steady`` (row1 - row0, W, 3) float32 the final steady state of those rows (NaN
        at unobserved points), so that a viewer can show the steady state before the open ends.
        Called from the opening thread; in-memory opens and reopens do not call it.

    Raises
    ------
    DatasetError
        For any problem with the manifest or a file, naming the file, and for a dataset larger
        than the budget whose store cannot be written or would not fit its disk.
    """
    if isinstance(path, Manifest):
        manifest = path
    else:
        manifest = load_manifest(path) if use_cache else read_manifest(path)
    max_radius = effective_max_radius(manifest, radius)
    height, width = manifest.height, manifest.width
    needed = response_memory_bytes((height, width), max_radius)
    budget = memory_budget() if memory_budget_bytes is None else int(memory_budget_bytes)
    location = cache.cache_location(manifest.folder) if use_cache else None
    advice = "; open with a smaller radius" if manifest.max_radius is None else ""
    if not fits_in_memory(needed, budget) and not use_cache:
        raise DatasetError(f"{manifest.path}: responses up to radius {max_radius:g} need {format_bytes(needed)}, "
                           f"over the memory budget of {format_bytes(budget)}, and without the cache there is "
                           f"no store to read them from{advice}")
    if not fits_in_memory(needed, budget) and needed > (free := _free_disk(location)):
        raise DatasetError(f"{manifest.path}: responses up to radius {max_radius:g} need {format_bytes(needed)}, "
                           f"more than the {format_bytes(free)} free for its store in {location.parent}{advice}")
    offsets = disc_offsets(max_radius)
    shape = (height, width, len(offsets), 3)
    dataset = partial(ImpulseDataset, manifest=manifest, max_radius=max_radius, offsets=offsets)
    # The store's key in two parts (module .cache): without an entry of this manifest nothing can be
    # reused and no file is stat'ed; the frames' identities then come from their reading.
    manifest_key = cache.manifest_key(manifest, max_radius) if use_cache else ""
    key, store = "", None
    if use_cache:
        sweep_abandoned(location)  # what a killed open left, gigabytes at paper scale
        if stored_manifest_key(location) == manifest_key:
            key = cache.stat_key(manifest, manifest_key)
            store = open_store(location, key, shape, budget // 2)
    if store is not None and needed <= min(budget, WHOLE_READ_BYTES):
        phase("reading the store")
        try:
            responses = store.window(0, height, 0, width)
        except DatasetError:  # a chunk failed its checksum: the entry is marked stale, rebuilt below
            store = None
        else:
            if progress is not None:
                progress(1.0)
            return dataset(responses=responses, lit_counts=store.lit_counts, observed=store.observed,
                           steady=store.steady, store=store, cache_key=key, channels=store.channels)
    if store is None:
        channels = dataset_channels(manifest, allow_outside)  # from the first frame's header alone
        assembler = Assembler(manifest, offsets, allow_outside, channels)
        tile = store_tile((height, width), len(offsets))
        if fits_in_memory(needed, budget):
            assembled = assemble_in_memory(assembler, budget, progress, 1.0 - WRITE_SHARE if use_cache else 1.0)
            key = _read_key(manifest, manifest_key, assembler) if use_cache else ""
            if use_cache:
                try:
                    with write_store(location, manifest_key, shape, tile, channels) as writer:
                        writer.key = key
                        write_manifest_copy(writer.folder, manifest)
                        write_assembled(writer, assembled, progress, 1.0 - WRITE_SHARE)
                except (OSError, RinglightError):  # no store: the next open assembles again
                    pass
                else:  # as a reopen has it: what a cluster's workers read (module .distributed of rings)
                    store = open_store(location, key, shape, budget // 2)
            return dataset(responses=assembled.responses, lit_counts=assembled.lit_counts,
                           observed=assembled.observed, steady=assembled.steady, store=store, cache_key=key,
                           channels=channels)
        try:
            with write_store(location, manifest_key, shape, tile, channels) as writer:
                write_manifest_copy(writer.folder, manifest)
                assemble_into_store(assembler, writer, budget, progress, preview)
                writer.key = key = _read_key(manifest, manifest_key, assembler)
        except OSError as error:
            raise DatasetError(f"{location}: cannot write the store that a dataset of "
                               f"{format_bytes(needed)} is read from ({error.strerror or error})") from None
        store = open_store(location, key, shape, budget // 2)
        if store is None:
            raise DatasetError(f"{location}: the store just written cannot be read back")
    elif progress is not None:
        progress(1.0)
    return dataset(responses=None, lit_counts=store.lit_counts, observed=store.observed, steady=store.steady,
                   store=store, cache_key=key, channels=store.channels)


def _read_key(manifest: Manifest, manifest_key: str, assembler: Assembler) -> str:
    """The store's key of what ``assembler`` read: the frames' identities as they were read (each
    file's ``fstat``), the dark and mapping files stat'ed."""
    return cache.files_key(manifest_key, assembler.identities, cache.other_identities(manifest))


def fits_in_memory(response_bytes: int, budget: int) -> bool:
    """Whether a response array of this size is assembled and kept in memory: it and the
    validity flags of one band of rows (at most 1/12 of it) fit the budget."""
    return response_bytes * 13 // 12 <= budget


def _free_disk(location: Path) -> int:
    """Bytes free on the file system that will hold ``location`` (its nearest existing parent)."""
    folder = location
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:  # an existing entry is replaced, so its space counts as free
        return shutil.disk_usage(folder).free + entry_bytes(location)
    except OSError:
        return 2**63
