"""The look-up tables of :mod:`.table` kept in the user cache beside their white runs.

Building a table from its white run (:func:`.table.build_table`) takes 1.2-3 CPU-s, paid again by
every process that fits optics; reading it back takes milliseconds. A table is kept as a checked
``.npz`` (:mod:`ringlight.core.checked_arrays`) in the white databases' folder, under their size
limit and their least-recently-used eviction (:mod:`ringlight.core.inversion.white_cache`), named
by a hash of its key: everything :func:`.table.table_for` keys its tables on (n, g, the rings,
photons, seed, the cut rings' weights), a digest of the white run's own arrays (a CUDA run takes
the place of a CPU run of as many photons, and is another sample of it), the table's grid and a
format version. A file that is damaged or holds another key's table is built again and replaced;
something other than a regular file in its place is a :class:`.radial.TableError` naming it, as
for the white runs.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from ..checked_arrays import DamagedFile, NotAFile, load_checked
from ..inversion import white_cache
from . import table as tables
from .radial import RadialRun, TableError

FORMAT_VERSION = 1
"""Raise it when :func:`.table.build_table` makes other numbers from the same run and grid: kept
tables of the old code are then built again."""
_ARRAYS = ("radii", "grid", "log_profile")
"""The arrays of a kept table; ``grid`` is (4,) float64 ``u0, du, v0, dv``."""


def table_key(run: RadialRun, radii: np.ndarray, thickness: float, antialias: bool, photons: int, seed: int,
              cut: str | None) -> str:
    """The text a kept table is named by and checked against: the table's arguments (``cut``: the
    SHA-256 of the cut rings' weights, or None), the run's digest and the grid's constants."""
    run_digest = hashlib.sha256(np.int64(run.photons).tobytes())
    for array in (run.weight, run.rho, run.path):
        run_digest.update(np.ascontiguousarray(array, np.float64).data)
    return json.dumps({"table": FORMAT_VERSION, "n": float(run.n), "g": float(run.g),
                       "radii": np.asarray(radii, np.float64).tolist(), "thickness": float(thickness),
                       "antialias": bool(antialias), "photons": int(photons), "seed": int(seed), "cut": cut,
                       "run": run_digest.hexdigest(),
                       "grid": [tables.REDUCED_SCATTERING_RANGE, tables.SCATTERING_POINTS, tables.ALBEDO_RANGE,
                                tables.ALBEDO_POINTS, tables.KERNEL_STEP, tables.AZIMUTHS, tables.SMALLEST_LOG]})


def table_path(key: str) -> Path:
    """Where the table of ``key`` lives: the white databases' folder, under a name their limit counts."""
    return white_cache.cache_folder() / f"{hashlib.sha256(key.encode()).hexdigest()[:24]}.npz"


def kept_table(run: RadialRun, radii: np.ndarray, thickness: float, antialias: bool, ring_weights: np.ndarray | None,
               photons: int, seed: int, cut: str | None) -> tables.ProfileTable:
    """The table of ``run`` for these rings (as :func:`.table.build_table` makes it) from the user
    cache, or built and kept there atomically; an unwritable cache only costs the next process the
    build."""
    limit = white_cache.cache_limit()
    key = table_key(run, radii, thickness, antialias, photons, seed, cut)
    path = table_path(key)
    try:
        arrays = load_checked(path, key, _ARRAYS)
    except NotAFile as error:
        raise TableError(f"{path}: not a look-up table of ringlight's ({error}); remove it to rebuild") from None
    except DamagedFile:
        arrays = None
    if arrays is not None and _plausible(arrays, radii):
        white_cache.mark_used(path)
        u0, du, v0, dv = (float(value) for value in arrays["grid"])
        return tables.ProfileTable(arrays["radii"], float(thickness), bool(antialias), run.n, run.g, u0, du, v0, dv,
                                   arrays["log_profile"], run.photons, run)
    table = tables.build_table(run, radii, thickness, antialias, ring_weights)
    white_cache.store(path, key, {"radii": table.radii, "grid": np.array([table.u0, table.du, table.v0, table.dv]),
                                  "log_profile": table.log_profile}, limit)
    return table


def _plausible(arrays: dict[str, np.ndarray], radii: np.ndarray) -> bool:
    """Whether checked ``arrays`` are a table of ``radii`` on the grid :func:`.table.build_table`
    makes (a file of this key written by other code is built again)."""
    grid, log_profile = arrays["grid"], arrays["log_profile"]
    return (arrays["radii"].dtype == np.float64 and np.array_equal(arrays["radii"], radii)
            and grid.dtype == np.float64 and grid.shape == (4,) and bool(np.isfinite(grid).all())
            and log_profile.dtype == np.float64
            and log_profile.shape == (tables.SCATTERING_POINTS, tables.ALBEDO_POINTS, len(radii))
            and bool(np.isfinite(log_profile).all()))
