"""The explorer's stacks and their noise estimate, kept on disk so that a reopen shows them at once.

A request's stacks (:func:`.stack_request.compute_stacks`), their standard errors
(:func:`.noise.stack_noise`) and their rings' coverage (:func:`.coverage.ring_coverage`) take most of a paper-scale open: at 800 x 800, R 24 about a minute
each, on every open, where the store itself reopens in a fraction of a second. Both are saved, a
folder each, under ``stacks/`` of the user cache folder (:func:`..dataset.cache.user_cache_root`),
named by a hash of what they depend on: the dataset's store key (its manifest, the identity of
every frame file and the radius: :func:`..dataset.cache.files_key`), the request, the kind and
:data:`VERSION`, which changes whenever the stacks' or the noise's arithmetic does. A dataset
opened without the cache (no key) is never cached.

An entry is a zarr v3 group (an image a chunk, Blosc-LZ4 with bit shuffling, a CRC-32C a chunk)
and ``meta.json`` with the key and the table of its files, each checked by its SHA-256 when read
(:mod:`..dataset.store_table`): an entry that is damaged, edited, partly lost or not of the shapes
the request gives is recomputed and replaced, never shown. Entries beyond :func:`cache_limit` are
removed, least recently used first (a limit of 0 saves nothing); nothing but the entries this module names (and the
temporaries of its killed saves) is ever removed, and a ``stacks`` that is a link is never used. Saving is best effort: a disk that would be left
with less than :data:`SPARE_BYTES` free, or a read-only cache, leaves the result uncached.

Measured on ``benchmarks/bench_scale.py``'s 800 px, R 24 dataset, the explorer's default request
(23 radii), a fresh process each: computed and saved 22.8 s (stacks), 21.4 s (noise) and 2.0 s
(coverage); read back 0.36 s, 0.47 s and 0.01 s; 120 MB on disk for them. The benchmark's
``explorer`` line times the whole open, dataset to noise, both ways.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import shutil
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..atomic import atomic_folder
from ..dataset.cache import user_cache_root
from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback
from ..dataset.memory import size_setting
from ..dataset.response_store import entry_bytes
from ..dataset.store_table import (
    META,
    TableStore,
    entry_table,
    most_bytes,
    read_checked,
    settle_reads,
    store_codecs,
    table_of,
)
from ..device import Device
from ..errors import RinglightError
from ..phases import phase
from ..staging_locks import sweep_abandoned
from ..validation import read_json
from .coverage import CoverageMeans, ring_coverage
from .noise import StackNoise, luminance_weights, stack_noise
from .stack_request import StackPair, StackRequest, compute_stacks
from .stacks import Stack

VERSION = 1
"""Changes whenever the arithmetic of the stacks, their noise or their coverage changes, so that no
entry of the old arithmetic is shown."""
CACHE_BYTES = 4 * 2**30
"""Default bound of the entries' total size (``$RINGLIGHT_STACK_CACHE`` overrides: ``2G``; ``0``
saves nothing); an 800 x 800 view's stacks and noise take up to 0.9 GiB raw, less compressed."""
SPARE_BYTES = 2**30
"""Free disk an entry must leave beside its raw size, or it is not saved."""
_ENTRY = re.compile(r"[0-9a-f]{32}")
_ABANDONED = re.compile(r"\.([0-9a-f]{32})\.(?:partial|old)-[0-9a-f]{12}")
_MAX_META_BYTES = 2**20
_MAX_METADATA_BYTES = 2**16
"""Largest zarr.json an entry's arrays or group can have (about 600 bytes each)."""
Shapes = dict[str, tuple[tuple[int, ...], str]]
"""An entry's arrays: name -> (shape, dtype name)."""


def cached_stacks(dataset: ImpulseDataset, request: StackRequest,
                  progress: ProgressCallback | None = None, device: Device | None = None) -> StackPair:
    """:func:`.stack_request.compute_stacks`, read from the cache when an entry of the same key
    is there and intact, else computed (on ``device``) and saved. ``progress`` may raise
    ``Cancelled``."""
    request.check(dataset)
    n, (height, width) = len(request.radii()), dataset.grid_shape
    images, counts = ((n, height, width, 3), "float32"), ((n, height, width), "int32")
    shapes = {"ring_radii": ((n,), "float64"), "ring_images": images, "ring_counts": counts,
              "transient_radii": ((n,), "float64"), "transient_images": images, "transient_counts": counts,
              "transient_outer_counts": counts}

    def arrays_of(pair: StackPair) -> dict[str, np.ndarray]:
        ring, transient = pair.ring, pair.transient
        return {"ring_radii": ring.radii, "ring_images": ring.images, "ring_counts": ring.counts,
                "transient_radii": transient.radii, "transient_images": transient.images,
                "transient_counts": transient.counts, "transient_outer_counts": transient.outer_counts}

    def pair_of(arrays: dict[str, np.ndarray]) -> StackPair:
        common = {"thickness": request.thickness, "antialias": request.antialias, "colorspace": dataset.colorspace}
        ring = Stack("ring", arrays["ring_radii"], images=arrays["ring_images"], counts=arrays["ring_counts"],
                     **common)
        transient = Stack("transient", arrays["transient_radii"], images=arrays["transient_images"],
                          counts=arrays["transient_counts"], outer_counts=arrays["transient_outer_counts"],
                          step=float(request.dr), **common)
        return StackPair(request, ring, transient)

    return _cached(dataset, "stacks", dataclasses.asdict(request), shapes,
                   ("reading the saved stacks", "computing the stacks"),
                   lambda: compute_stacks(dataset, request, progress, device), arrays_of, pair_of)


def cached_noise(dataset: ImpulseDataset, request: StackRequest,
                 progress: ProgressCallback | None = None) -> StackNoise:
    """:func:`.noise.stack_noise` of ``request``'s radii, read from the cache when an entry of the
    same key is there and intact, else computed and saved. ``progress`` may raise ``Cancelled``."""
    n, (height, width) = len(request.radii()), dataset.grid_shape
    images, luminance = ((n, height, width, 3), "float32"), ((n, height, width), "float32")
    shapes = {"radii": ((n,), "float64"), "ring": images, "transient": images, "ring_luminance": luminance,
              "transient_luminance": luminance}

    def arrays_of(noise: StackNoise) -> dict[str, np.ndarray]:
        return {name: getattr(noise, name) for name in shapes}

    def noise_of(arrays: dict[str, np.ndarray]) -> StackNoise:
        return StackNoise(arrays["radii"], float(request.dr), arrays["ring"], arrays["transient"],
                          arrays["ring_luminance"], arrays["transient_luminance"],
                          luminance_weights(dataset.colorspace))

    return _cached(dataset, "noise", dataclasses.asdict(request), shapes,
                   ("reading the saved noise estimate", "estimating the noise"),
                   lambda: stack_noise(dataset, request.radii(), request.dr, request.thickness, request.antialias,
                                       progress),
                   arrays_of, noise_of)


def cached_coverage(dataset: ImpulseDataset, request: StackRequest) -> CoverageMeans:
    """The means of :func:`.coverage.ring_coverage` of ``request``'s radii and thickness, read
    from the cache when an entry of the same key is there and intact, else computed and saved."""
    radii = request.radii()
    shapes = {name: ((len(radii),), "float64") for name in ("radii", "member_fraction", "nearest_offset")}
    return _cached(dataset, "coverage", {"radii": radii.tolist(), "thickness": request.thickness}, shapes,
                   ("reading the saved ring coverage", "measuring the rings' coverage"),
                   lambda: ring_coverage(dataset, radii, request.thickness).means(),
                   lambda means: {name: getattr(means, name) for name in shapes},
                   lambda arrays: CoverageMeans(arrays["radii"], arrays["member_fraction"], arrays["nearest_offset"]))


def _cached(dataset: ImpulseDataset, kind: str, parameters: dict, shapes: Shapes, phases: tuple[str, str],
            compute: Callable[[], Any], arrays_of: Callable[[Any], dict[str, np.ndarray]],
            result_of: Callable[[dict[str, np.ndarray]], Any]) -> Any:
    """``result_of`` the arrays of the entry of ``kind`` and ``parameters`` when it is there and
    intact, else ``compute()``, saved as ``arrays_of`` it; ``phases`` names reading and computing.
    A limit that is not a size is named before any work, and a limit of 0 saves nothing."""
    limit = cache_limit()
    key = _key(dataset, kind, parameters)
    arrays = _load(key, shapes, phases[0]) if key else None
    if arrays is not None:
        return result_of(arrays)
    phase(phases[1])
    result = compute()
    if key and limit > 0:
        _save(key, arrays_of(result), limit)
    return result


def cache_folder() -> Path:
    """Where the entries live (not created)."""
    return user_cache_root() / "stacks"


def cache_limit() -> int:
    """Bytes the entries may take together: ``$RINGLIGHT_STACK_CACHE`` or :data:`CACHE_BYTES`.
    Raises RinglightError naming the variable when it is not a size."""
    return size_setting("RINGLIGHT_STACK_CACHE", CACHE_BYTES)


def _key(dataset: ImpulseDataset, kind: str, parameters: dict) -> str:
    """The full key of the entry of ``kind`` computed with ``parameters`` (JSON values) from
    ``dataset``; empty without a store key."""
    if not dataset.cache_key:
        return ""
    text = json.dumps({"version": VERSION, "kind": kind, "dataset": dataset.cache_key, "parameters": parameters},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _load(key: str, shapes: Shapes, what: str) -> dict[str, np.ndarray] | None:
    """The arrays of the entry for ``key`` when it is there, intact and exactly of ``shapes``, its
    reading named phase ``what``; else None. The table must list exactly the files those arrays
    are written as (a chunk it did not list would read as zarr's fill value), and any failure of
    a read is a miss: the caller computes the arrays again."""
    root = _root()
    if root is None:
        return None
    folder = root / key[:32]
    try:
        if not stat.S_ISDIR(os.lstat(folder).st_mode) or not stat.S_ISREG(os.lstat(folder / META).st_mode):
            return None
    except OSError:  # no entry: the usual miss
        return None
    reading = False
    try:
        meta = read_json(folder / META, _EntryInvalid, "cache meta.json", max_bytes=_MAX_META_BYTES)
        if not isinstance(meta, dict) or meta.get("key") != key:
            return None
        table, largest = entry_table(folder, meta), _files_of(shapes)
        if table is None or set(table) != set(largest) or any(table[name][0] > largest[name] for name in table) \
                or any(json.loads(read_checked(folder, name, table)) != written
                       for name, written in _metadata_of(shapes, key).items()):
            return None
        phase(what)
        reading = True
        group = zarr.open_group(TableStore(folder, table), mode="r", zarr_format=3)
        arrays = {}
        for name, (shape, dtype) in shapes.items():
            array = group[name]
            if not isinstance(array, zarr.Array) or array.shape != shape or array.dtype != np.dtype(dtype) \
                    or array.chunks != _chunks(shape):
                return None
            arrays[name] = array[...]
    except Exception:  # noqa: BLE001 - whatever a damaged or planted entry raises, it is recomputed
        if reading:
            settle_reads()
        return None
    try:
        os.utime(folder, follow_symlinks=False)  # the least recently used entries are removed first
    except (OSError, NotImplementedError):
        pass
    return arrays


def _root() -> Path | None:
    """:func:`cache_folder` when it is a real folder or absent, else None: a link there (to a
    user's folder) is never written into, read or trimmed."""
    root = cache_folder()
    try:
        return root if stat.S_ISDIR(os.lstat(root).st_mode) else None
    except FileNotFoundError:
        return root
    except OSError:
        return None


def _create(group: zarr.Group, name: str, shape: tuple[int, ...], dtype) -> zarr.Array:
    """An entry's array: an image (or a radius's values) a chunk, LZ4 with bit shuffling, CRC-32C."""
    return group.create_array(name, shape=shape, chunks=_chunks(shape), dtype=dtype, compressors=store_codecs(),
                              config={"write_empty_chunks": True})


def _metadata_of(shapes: Shapes, key: str) -> dict[str, dict]:
    """The metadata files (relative path -> their JSON) that :func:`_create` writes for arrays of
    ``shapes`` in the entry for ``key``: an entry's must be exactly these (an edited byte order,
    codec or chunk naming, recorded in the table, would still read, as other numbers; the key in
    the group's attributes keeps another request's entry, its meta.json's key edited, out)."""
    store = zarr.storage.MemoryStore()
    group = zarr.open_group(store, mode="w", attributes={"key": key})
    for name, (shape, dtype) in shapes.items():
        _create(group, name, shape, dtype)
    prototype = zarr.core.buffer.default_buffer_prototype()
    return {path: json.loads(zarr.core.sync.sync(store.get(path, prototype)).to_bytes())
            for path in ["zarr.json", *(f"{name}/zarr.json" for name in shapes)]}


def _chunks(shape: tuple[int, ...]) -> tuple[int, ...]:
    """An entry array's chunks: an image (or a radius's values) a chunk, a 1-d array whole."""
    return (1, *shape[1:]) if len(shape) > 1 else shape


def _files_of(shapes: Shapes) -> dict[str, int]:
    """The files zarr writes for arrays of ``shapes`` in :func:`_chunks`, but meta.json, each with
    the most bytes it can take (a chunk's raw bytes and the codecs' overhead), so that a file the
    table says is larger is never read."""
    files = {"zarr.json": _MAX_METADATA_BYTES}
    for name, (shape, dtype) in shapes.items():
        files[f"{name}/zarr.json"] = _MAX_METADATA_BYTES
        chunks = _chunks(shape)
        raw = int(np.prod(chunks)) * np.dtype(dtype).itemsize
        for index in np.ndindex(*(-(-size // chunk) for size, chunk in zip(shape, chunks))):
            files[f"{name}/c/" + "/".join(map(str, index))] = most_bytes(raw)
    return files


def _save(key: str, arrays: dict[str, np.ndarray], limit: int) -> None:
    """Save ``arrays`` (name -> array, an image or a radius's values a chunk) as the entry for
    ``key``, then trim the cache to ``limit`` bytes; gives up quietly when it cannot."""
    root = _root()
    if root is None:
        return
    folder = root / key[:32]
    raw = sum(array.nbytes for array in arrays.values())
    try:
        root.mkdir(parents=True, exist_ok=True)
        if shutil.disk_usage(root).free < raw + SPARE_BYTES:
            return
        sweep_abandoned(folder)
        phase("saving the result for the next open")
        with atomic_folder(folder) as staging:
            group = zarr.open_group(zarr.storage.LocalStore(staging), mode="w", attributes={"key": key})
            for name, array in arrays.items():
                _create(group, name, array.shape, array.dtype)[...] = array
            meta = {"key": key, "table": table_of(staging)}
            (staging / META).write_text(json.dumps(meta), encoding="utf-8")
        _trim(root, folder.name, limit)
    except (OSError, RinglightError, RecursionError):  # RecursionError: a planted chain of folders
        return


def _trim(root: Path, keep: str, limit: int) -> None:
    """Remove the least recently used entries under ``root`` (folders of 32 hex digits holding a
    meta.json whose key they are named by; ``keep`` never) until the rest take at most ``limit``
    bytes, and the temporaries that killed saves abandoned."""
    entries = []
    try:
        with os.scandir(root) as found:
            names = [entry.name for entry in found if entry.is_dir(follow_symlinks=False)]
    except OSError:
        return
    for name in names:
        abandoned = _ABANDONED.fullmatch(name)
        if abandoned:
            sweep_abandoned(root / abandoned.group(1))
        elif _ENTRY.fullmatch(name) and name != keep and _written_here(root / name):
            try:
                entries.append((os.lstat(root / name).st_mtime, name, entry_bytes(root / name)))  # mtime: last load
            except OSError:
                continue
    total = entry_bytes(root / keep) + sum(size for *_, size in entries)
    for _, name, size in sorted(entries):
        if total <= limit:
            break
        shutil.rmtree(root / name, ignore_errors=True)
        total -= size


def _written_here(folder: Path) -> bool:
    """Whether ``folder`` is an entry this module wrote: a meta.json whose key it is named by
    (a user's folder of 32 hex digits is never trimmed)."""
    try:
        if not stat.S_ISREG(os.lstat(folder / META).st_mode):
            return False
        meta = read_json(folder / META, _EntryInvalid, "cache meta.json", max_bytes=_MAX_META_BYTES)
    except (OSError, RinglightError):
        return False
    return isinstance(meta, dict) and isinstance(meta.get("key"), str) and meta["key"][:32] == folder.name


class _EntryInvalid(RinglightError):
    """An entry's meta.json that cannot be read; the entry is recomputed, so users never see this."""
