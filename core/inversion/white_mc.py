"""The white Monte Carlo of a layered slab: one simulation without absorption, reweighted for any
absorption per depth bin (the scaling or "white" Monte Carlo of biomedical optics; Graaff et al.
1993, Alerstam et al. 2008).

Geometry and estimator are the simulator's (:mod:`ringlight.core.simulate.photon`,
:mod:`ringlight.core.simulate.camera`): a laterally homogeneous slab of index ``n`` below a flat
surface, ``depth`` grid steps deep (light crossing ``z = depth`` is lost), the beam straight down
entering uniformly over the lit pixel with the Fresnel transmission as its weight, the camera
straight down (docs/format/scene.md, "What a simulated frame holds"). Lengths are in grid steps, coefficients
per grid step.

The scattering coefficient may differ per depth bin (bin ``b < B - 1`` is ``[b, b + 1)``, the last
one ``[B - 1, depth)``); the walk has no absorption. At every real scattering within
``reach`` pixels of the lit point the camera's next-event estimate with ``cos th_i = 1``,

    v = T_entry pi T_F(0) / n^2  p_HG(-u_z)  exp(-sum_b mus_b up_b),

is recorded with its pixel and its path length in each bin, ``l_b`` (the walk so far plus the
leg ``up_b`` straight up to the surface). In the medium with absorption ``mua_b`` per bin and the
same ``mus``, ``g``, ``n``, the walk's probability changes by ``exp(-sum_b mua_b l_b)``: the same
estimate is ``v exp(-sum_b mua_b l_b)``, exactly, for any absorption.

Estimates below :data:`THIN_VALUE` (from deep vertices) are kept with probability
``v / THIN_VALUE`` at value ``THIN_VALUE`` (unbiased), which bounds the number of records.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from ..checked_arrays import DamagedFile, NotAFile, load_checked
from ..device import Device
from ..errors import RinglightError
from ..simulate.steps import CPU, Steps
from ..simulate.streams import ESTIMATOR_STREAM, seed_state
from . import white_cache

THIN_VALUE = 1e-3
BLOCKS = 32
"""Photons run in this many blocks, one random stream each (results do not depend on threads)."""
CHUNK = 4
"""Blocks run in parallel between progress reports."""
FORMAT_VERSION = 1
OPTICAL_DEPTH_CUTOFF = 40.0


class DatabaseError(RinglightError):
    """A white Monte Carlo database cannot be made or read."""


@dataclass(frozen=True)
class SlabOptics:
    """What a white database depends on.

    Attributes
    ----------
    mus
        (B,) scattering coefficient per depth bin, per grid step; the last bin reaches ``depth``.
    g, n
        Henyey-Greenstein anisotropy and refractive index.
    depth
        Grid steps below the surface where light is lost (>= B - 1 + a fraction).
    reach
        Records are kept for pixels with ``|dy|, |dx| <= reach`` of the lit pixel.
    """

    mus: tuple[float, ...]
    g: float
    n: float
    depth: float
    reach: int

    def __post_init__(self):
        # One type per field: a depth of 24 and of 24.0 are the same optics, so they must give the
        # same cache key (json writes "24" and "24.0") and the same compiled walk (numba compiled
        # the walk once for each: 8 s more).
        object.__setattr__(self, "mus", tuple(float(m) for m in self.mus))
        for name in ("g", "n", "depth"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "reach", int(self.reach))

    @property
    def bins(self) -> int:
        return len(self.mus)

    def key(self, photons: int, seed: int) -> str:
        text = json.dumps({"mus": self.mus, "g": self.g, "n": self.n, "depth": self.depth, "reach": self.reach,
                           "photons": photons, "seed": seed, "version": FORMAT_VERSION, "thin": THIN_VALUE})
        return hashlib.sha256(text.encode()).hexdigest()[:24]


@dataclass(frozen=True, eq=False)
class WhiteDatabase:
    """The records of a white run.

    Attributes
    ----------
    optics
        What it was run for.
    photons
        Photons traced.
    pixel
        (M,) int32 index of each record's pixel, ``(dy + reach) * (2 reach + 1) + dx + reach``.
    value
        (M,) float32 next-event estimate without absorption.
    lengths
        (M, B) float32 path length in each depth bin, grid steps.
    photon
        (M,) int32 the photon each record belongs to (0 .. photons - 1), for the run's own variance.
    seconds
        Time the run took.
    """

    optics: SlabOptics
    photons: int
    pixel: np.ndarray
    value: np.ndarray
    lengths: np.ndarray
    photon: np.ndarray
    seconds: float



def depth_bin(z, bins):
    """The depth bin of depth ``z`` among ``bins`` (the last one reaches the slab's depth)."""
    return min(int(z), bins - 1)


def write_record(row, pixel, value, lengths_out, photon_out, cell, estimate, lengths, up, photon):
    """Row ``row`` of the records, when there is room: the estimate's pixel ``cell``, its value and
    photon, and its path length per bin (the walk's ``lengths`` plus the leg ``up``)."""
    if row < pixel.shape[0]:
        pixel[row] = cell
        value[row] = estimate
        for b in range(lengths_out.shape[1]):
            lengths_out[row, b] = lengths[b] + up[b]
        photon_out[row] = photon


_write_record = numba.njit(cache=True, inline="always")(write_record)


def keep_record(count, counter, pixel, value, lengths_out, photon_out, cell, estimate, lengths, up, photon):
    """The CPU's record: row ``count`` (:func:`write_record`); returns ``count + 1`` (a CUDA
    kernel takes its row from the atomic ``counter`` instead; the CPU's is unused)."""
    _write_record(count, pixel, value, lengths_out, photon_out, cell, estimate, lengths, up, photon)
    return count + 1


def compile_walk(jit, steps: Steps, record):
    """``trace_photon(state, estimator_state, mus, majorant, g, n, depth, reach, constant, lengths,
    up, photon, count, counter, pixel, value, lengths_out, photon_out)`` compiled with ``jit`` from the
    device's ``steps`` (:func:`ringlight.core.simulate.steps.compile_steps`) and its compiled
    ``record`` (as :func:`keep_record`): photon number ``photon`` traced without absorption on
    ``state`` (its thinning on ``estimator_state``), its estimates recorded; ``constant`` =
    ``T_entry pi T_F(0) / n^2``, ``lengths`` and ``up`` scratch of at least B. Returns ``count``
    plus the records made. The one statement of the walk that the CPU and the CUDA kernels compile."""
    uniform, exit_fresnel, henyey_greenstein = steps.uniform, steps.exit_fresnel, steps.henyey_greenstein
    flight_to_surface, scatter, bin_of = steps.flight_to_surface, steps.scatter, jit(depth_bin)

    def add_flight(lengths, bins, z0, z1, step):
        """Add a flight of ``step`` from depth ``z0`` to ``z1`` to ``lengths[:bins]`` bin by bin."""
        b0 = bin_of(z0, bins)
        b1 = bin_of(z1, bins)
        if b0 == b1:
            lengths[b0] += step
            return
        low = min(z0, z1)
        high = max(z0, z1)
        per_depth = step / (high - low)
        for b in range(min(b0, b1), max(b0, b1) + 1):
            bottom = b + 1.0 if b < bins - 1 else math.inf
            overlap = min(high, bottom) - max(low, float(b))
            if overlap > 0.0:
                lengths[b] += overlap * per_depth

    flight = jit(add_flight)

    def trace_photon(state, estimator_state, mus, majorant, g, n, depth, reach, constant, lengths, up, photon, count,
                     counter, pixel, value, lengths_out, photon_out):
        bins = mus.shape[0]
        side = 2 * reach + 1
        y = uniform(state) - 0.5
        x = uniform(state) - 0.5
        z = 0.0
        uy, ux, uz = 0.0, 0.0, 1.0
        for b in range(bins):
            lengths[b] = 0.0
        while True:
            step = -math.log(1.0 - uniform(state)) / majorant
            travel = flight_to_surface(z, uz, step)
            if travel >= 0.0:
                flight(lengths, bins, z, 0.0, travel)
                y += travel * uy
                x += travel * ux
                z = 0.0
                if uniform(state) < exit_fresnel(n, -uz):
                    uz = -uz
                    continue
                return count
            if uz > 0.0 and z + step * uz >= depth:
                return count
            z_next = z + step * uz
            flight(lengths, bins, z, z_next, step)
            y += step * uy
            x += step * ux
            z = z_next
            if uniform(state) * majorant >= mus[bin_of(z, bins)]:
                continue
            dy = int(math.floor(y + 0.5))
            dx = int(math.floor(x + 0.5))
            if abs(dy) <= reach and abs(dx) <= reach:
                tau = 0.0
                for b in range(bins):
                    top = float(b)
                    if top >= z:
                        up[b] = 0.0
                        continue
                    bottom = b + 1.0 if b < bins - 1 else math.inf
                    up[b] = min(z, bottom) - top
                    tau += mus[b] * up[b]
                if tau < OPTICAL_DEPTH_CUTOFF:
                    estimate = constant * henyey_greenstein(-uz, g) * math.exp(-tau)
                    keep = True
                    if estimate < THIN_VALUE:
                        keep = uniform(estimator_state) * THIN_VALUE < estimate
                        estimate = THIN_VALUE
                    if keep:
                        count = record(count, counter, pixel, value, lengths_out, photon_out,
                                       (dy + reach) * side + dx + reach, estimate, lengths, up, photon)
            uy, ux, uz = scatter(state, uy, ux, uz, g)

    return jit(trace_photon)


_camera_constant = CPU.camera_constant
_CPU_JIT = numba.njit(cache=True, inline="always")
_trace_photon = compile_walk(_CPU_JIT, CPU, _CPU_JIT(keep_record))


@numba.njit(cache=True)
def _white_block(mus, g, n, depth, reach, photons, first_photon, seed, stream, pixel, value, lengths_out, photon_out):
    """Trace ``photons`` photons on stream ``stream`` and write their records from row 0 while there
    is room; returns how many records they made (more than the rows: the caller retries)."""
    bins = mus.shape[0]
    majorant = mus.max()
    state = seed_state(seed, stream)
    estimator_state = seed_state(seed, stream + ESTIMATOR_STREAM)
    constant = _camera_constant(n)
    lengths = np.zeros(bins)
    up = np.zeros(bins)
    unused_counter = np.zeros(1, np.int64)
    count = 0
    for p in range(photons):
        count = _trace_photon(state, estimator_state, mus, majorant, g, n, depth, reach, constant, lengths, up,
                              first_photon + p, count, unused_counter, pixel, value, lengths_out, photon_out)
    return count


@numba.njit(parallel=True, cache=True, nogil=True)
def _white_blocks(mus, g, n, depth, reach, per_block, seed, first, pixel, value, lengths, photon, counts):
    """:func:`_white_block` for blocks ``first, first + 1, ...`` (rows ``pixel[i]`` etc. for block
    ``first + i``) in parallel; ``counts[i]``."""
    for i in numba.prange(counts.shape[0]):
        b = first + i
        counts[i] = _white_block(mus, g, n, depth, reach, per_block, b * per_block, seed, b, pixel[i], value[i],
                                 lengths[i], photon[i])


def run_white(optics: SlabOptics, photons: int, seed: int = 0, progress=None,
              device: Device | None = None) -> WhiteDatabase:
    """Trace ``photons`` (rounded up to a multiple of :data:`BLOCKS`) without absorption;
    ``progress(fraction)`` after each :data:`CHUNK` blocks (raise from it to cancel; once at the
    end on a GPU). On a CUDA ``device`` the run is :func:`.white_cuda.run_white_cuda`'s."""
    if device is not None and device.is_cuda:
        from .white_cuda import run_white_cuda

        database = run_white_cuda(optics, photons, seed)
        if progress is not None:
            progress(1.0)
        return database
    start = time.perf_counter()
    mus = np.asarray(optics.mus, np.float64)
    per_block = -(-photons // BLOCKS)
    bins = optics.bins
    # A pilot of one block's first photons sizes the buffers; a block that overflows runs again.
    probe = max(1, min(per_block, 64))
    pilot = _white_block(mus, optics.g, optics.n, optics.depth, optics.reach, probe, 0, seed, 0,
                         np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros((0, bins), np.float32),
                         np.zeros(0, np.int32))
    capacity = int(1.3 * pilot * per_block / probe) + 1024
    parts = []
    for first in range(0, BLOCKS, CHUNK):
        pixel = np.zeros((CHUNK, capacity), np.int32)
        value = np.zeros((CHUNK, capacity), np.float32)
        lengths = np.zeros((CHUNK, capacity, bins), np.float32)
        photon = np.zeros((CHUNK, capacity), np.int32)
        counts = np.zeros(CHUNK, np.int64)
        _white_blocks(mus, optics.g, optics.n, optics.depth, optics.reach, per_block, seed, first, pixel, value,
                      lengths, photon, counts)
        for i in range(CHUNK):
            if counts[i] <= capacity:
                parts.append((pixel[i, :counts[i]].copy(), value[i, :counts[i]].copy(), lengths[i, :counts[i]].copy(),
                              photon[i, :counts[i]].copy()))
                continue
            size = int(counts[i])
            again = (np.zeros(size, np.int32), np.zeros(size, np.float32), np.zeros((size, bins), np.float32),
                     np.zeros(size, np.int32))
            b = first + i
            _white_block(mus, optics.g, optics.n, optics.depth, optics.reach, per_block, b * per_block, seed, b,
                         *again)
            parts.append(again)
        if progress is not None:
            progress((first + CHUNK) / BLOCKS)
    return WhiteDatabase(optics, per_block * BLOCKS, np.concatenate([p[0] for p in parts]),
                         np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts]),
                         np.concatenate([p[3] for p in parts]), time.perf_counter() - start)


def database_path(optics: SlabOptics, photons: int, seed: int) -> Path:
    """Where the database of these optics lives in the user cache."""
    return white_cache.cache_folder() / f"{optics.key(photons, seed)}.npz"


def white_database(optics: SlabOptics, photons: int, seed: int = 0, use_cache: bool = True,
                   progress=None, device: Device | None = None) -> WhiteDatabase:
    """The database of ``optics`` from the user cache (:mod:`.white_cache`), or run (and cached
    atomically, the least recently used databases then dropped down to the cache's limit);
    ``progress`` and ``device`` as :func:`run_white` takes them (a CUDA run of as many photons,
    another sample of the same run, takes the same place in the cache)."""
    path = database_path(optics, photons, seed)
    limit = white_cache.cache_limit() if use_cache else 0  # a bad setting is told before the run
    if use_cache and (database := _cached(path, optics, photons)) is not None:
        white_cache.mark_used(path)
        return database
    database = run_white(optics, photons, seed, progress, device)
    if use_cache:
        white_cache.store(path, path.stem, {"photons": np.int64(database.photons), "pixel": database.pixel,
                                            "value": database.value, "lengths": database.lengths,
                                            "photon": database.photon, "seconds": np.float64(database.seconds)},
                          limit)
    return database


_ARRAYS = ("photons", "pixel", "value", "lengths", "photon", "seconds")


def _cached(path: Path, optics: SlabOptics, photons: int) -> WhiteDatabase | None:
    """The database stored at ``path``; None when there is none (or another process's eviction
    dropped it meanwhile), or when the file is damaged (truncated, a flipped bit, another run's,
    records no run could make: :mod:`..checked_arrays`), so that it is run again and replaced.
    Raises DatabaseError naming the file when something other than a regular file is there (a
    FIFO: read, it blocked for good)."""
    try:
        data = load_checked(path, path.stem, _ARRAYS)
        return None if data is None else _checked_database(data, optics, photons)
    except NotAFile as error:
        raise DatabaseError(f"{path}: not a white Monte Carlo database ({error}); remove it to rerun") from None
    except DamagedFile:
        return None


def _checked_database(data: dict[str, np.ndarray], optics: SlabOptics, photons: int) -> WhiteDatabase:
    """``data`` as a :class:`WhiteDatabase` of ``optics``, or DamagedFile when no run of
    ``photons`` photons could have recorded it."""
    traced, pixel, value, lengths, photon, seconds = (data[name] for name in _ARRAYS)
    records = len(pixel)
    if (traced.shape != () or int(traced) != -(-photons // BLOCKS) * BLOCKS or seconds.shape != ()
            or not 0 <= float(seconds) < np.inf):
        raise DamagedFile("its photon count or time is not this run's")
    if (pixel.shape != (records,) or value.shape != (records,) or photon.shape != (records,)
            or lengths.shape != (records, optics.bins) or pixel.dtype != np.int32 or photon.dtype != np.int32
            or value.dtype != np.float32 or lengths.dtype != np.float32):
        raise DamagedFile("its records do not fit together")
    if records and (pixel.min() < 0 or pixel.max() >= (2 * optics.reach + 1) ** 2 or photon.min() < 0
                    or photon.max() >= int(traced) or not np.isfinite(value).all() or value.min() < 0
                    or not np.isfinite(lengths).all() or lengths.min() < 0):
        raise DamagedFile("its records are out of range")
    return WhiteDatabase(optics, int(traced), pixel, value, lengths, photon, float(seconds))
