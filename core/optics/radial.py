"""The white Monte Carlo of a homogeneous half-space in units of the scattering mean free path:
one run per refractive index ``n`` and anisotropy ``g`` serves every scattering coefficient, by
scaling, and every absorption, by reweighting.

In a homogeneous medium of scattering coefficient ``mus`` every length of a walk is a length in
mean free paths ``1 / mus``: a run at ``mus = 1`` without absorption, that records each camera
estimate with its *continuous* lateral distance ``rho`` from the entry point and its path length
``L`` (both in mean free paths), stands for the medium of any ``mus`` (lengths ``rho / mus`` and
``L / mus`` grid steps) and any absorption ``mua`` (weight ``exp(-mua L / mus)``, exact: the white
Monte Carlo of Graaff et al. 1993, Alerstam et al. 2008). The walk and its estimator are the
simulator's and the layer inversion's (:mod:`ringlight.core.inversion.white_mc`: beam straight down
entering with the Fresnel transmission as its weight, next-event estimate toward a camera straight
down ``v = T_entry pi T_F(0) / n^2 p_HG(-u_z) exp(-z)`` at every scattering); only the record is
different: ``rho`` continuous rather than the pixel it falls in, so that the pixel geometry is
applied afterwards for each ``mus`` (:mod:`.table`).

The records are tallied as they come into cells of ``log rho`` and ``log L`` (ratio
:data:`RATIO`), each keeping its weight ``W = sum v`` and the weighted sums of ``rho`` and ``L``
(the cell's means stand for its records). A photon is followed until it leaves or its path
reaches :data:`LONGEST` transport mean free paths: what such a path carries is below
``exp(-mua LONGEST / mus')``: 0.7 % where ``mua / mus' = 1e-3`` (0.005 / mm absorption under 5 / mm
reduced scattering), and few paths are that long (in a half-space the share longer than ``L``
falls as ``L^-1/2``: about 1 %). Weaker absorption relative to the scattering loses more; the
fits there are not determined anyway (``tools/evaluate_optics.py``).
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
from ..inversion import white_cache
from ..simulate.steps import CPU, Steps
from ..simulate.streams import seed_state

RATIO = 1.02
"""Ratio between consecutive cells of ``rho`` and of ``L``."""
SHORTEST_RHO = 1e-3
"""Mean free paths: the first ``rho`` cell's start (nearer records share it)."""
FARTHEST_RHO = 600.0
"""Mean free paths: records farther from the entry point are not kept (the walk goes on)."""
SHORTEST_PATH = 1e-2
LONGEST = 5e3
"""Transport mean free paths (``1 / (mus (1 - g))``): a walk stops when its path reaches this
length (``LONGEST / (1 - g)`` mean free paths)."""
MOST_ANISOTROPIC = 0.95
"""Largest ``|g|`` a run is made for (its walks are ``1 / (1 - g)`` times longer)."""
DEEPEST = 40.0
"""Optical depth past which an estimate (below exp(-40) of the walk's weight) is dropped."""
BLOCKS = 16
"""Photons run in this many blocks of one random stream each (results do not depend on threads)."""
CHUNK = 4
"""Blocks run in parallel between progress reports."""
FORMAT_VERSION = 1
RHO_CELLS = 1 + int(math.ceil(math.log(FARTHEST_RHO / SHORTEST_RHO) / math.log(RATIO)))
PATH_CELLS = 1 + int(math.ceil(math.log(LONGEST / (1.0 - MOST_ANISOTROPIC) / SHORTEST_PATH) / math.log(RATIO)))
_ARRAYS = ("photons", "weight", "rho", "path", "seconds")


class TableError(RinglightError):
    """A white run of a homogeneous medium cannot be made or read."""


@dataclass(frozen=True, eq=False)
class RadialRun:
    """A white run of a half-space, tallied in cells of ``(rho, L)``.

    Attributes
    ----------
    n, g
        Refractive index and Henyey-Greenstein anisotropy.
    photons
        Photons traced.
    weight
        (RHO_CELLS, PATH_CELLS) float64: each cell's summed estimates ``W`` (per photon: divide by
        ``photons``).
    rho, path
        (RHO_CELLS, PATH_CELLS) float64: each cell's weighted mean lateral distance and path
        length, mean free paths (0 where ``W`` is 0).
    seconds
        Time the run took.
    device
        What traced it: ``"cpu"``, or ``"cuda"`` (:mod:`.radial_cuda`: other random streams, so
        another sample of the same run); a run read from the cache says ``"cpu"``.
    """

    n: float
    g: float
    photons: int
    weight: np.ndarray
    rho: np.ndarray
    path: np.ndarray
    seconds: float
    device: str = "cpu"


def cell(value, shortest, cells):
    """The log-spaced cell (ratio :data:`RATIO`) of ``value`` among ``cells`` from ``shortest``
    (0 below it, the last one beyond the range)."""
    if value < shortest:
        return 0
    return min(1 + int(math.log(value / shortest) / math.log(RATIO)), cells - 1)


def add_to_cell(sums, i, j, value):
    """``sums[i, j] += value`` (the CPU's tally; a CUDA kernel's adds atomically)."""
    sums[i, j] += value


def compile_walk(jit, steps: Steps, add):
    """``trace_photon(state, g, n, longest, constant, weight, rho_sum, path_sum)``, compiled with
    ``jit`` from the device's ``steps`` (:func:`ringlight.core.simulate.steps.compile_steps`) and
    its compiled tally ``add`` (as :func:`add_to_cell`): one photon of the run traced on ``state``
    (``constant`` = ``T_entry pi T_F(0) / n^2``) and its estimates added to the cell sums. The one
    statement of the walk that the CPU and the CUDA kernels compile."""
    uniform, exit_fresnel, henyey_greenstein = steps.uniform, steps.exit_fresnel, steps.henyey_greenstein
    flight_to_surface, scatter, cell_of = steps.flight_to_surface, steps.scatter, jit(cell)

    def trace_photon(state, g, n, longest, constant, weight, rho_sum, path_sum):
        y = 0.0
        x = 0.0
        z = 0.0
        uy, ux, uz = 0.0, 0.0, 1.0
        length = 0.0
        while length < longest:
            step = -math.log(1.0 - uniform(state))
            travel = flight_to_surface(z, uz, step)
            if travel >= 0.0:
                length += travel
                y += travel * uy
                x += travel * ux
                z = 0.0
                if uniform(state) < exit_fresnel(n, -uz):
                    uz = -uz
                    continue
                break
            length += step
            y += step * uy
            x += step * ux
            z += step * uz
            if z < DEEPEST:
                rho = math.sqrt(y * y + x * x)
                if rho < FARTHEST_RHO:
                    estimate = constant * henyey_greenstein(-uz, g) * math.exp(-z)
                    path = length + z
                    i = cell_of(rho, SHORTEST_RHO, RHO_CELLS)
                    j = cell_of(path, SHORTEST_PATH, PATH_CELLS)
                    add(weight, i, j, estimate)
                    add(rho_sum, i, j, estimate * rho)
                    add(path_sum, i, j, estimate * path)
            uy, ux, uz = scatter(state, uy, ux, uz, g)

    return jit(trace_photon)


_camera_constant = CPU.camera_constant
_CPU_JIT = numba.njit(cache=True, inline="always")
_trace_photon = compile_walk(_CPU_JIT, CPU, _CPU_JIT(add_to_cell))


@numba.njit(cache=True)
def _radial_block(g, n, longest, photons, seed, stream, weight, rho_sum, path_sum):
    """Trace ``photons`` on stream ``stream`` and add their estimates to the cell sums."""
    state = seed_state(seed, stream)
    constant = _camera_constant(n)
    for _ in range(photons):
        _trace_photon(state, g, n, longest, constant, weight, rho_sum, path_sum)


@numba.njit(parallel=True, cache=True, nogil=True)
def _radial_blocks(g, n, longest, per_block, seed, first, weight, rho_sum, path_sum):
    for i in numba.prange(weight.shape[0]):
        _radial_block(g, n, longest, per_block, seed, first + i, weight[i], rho_sum[i], path_sum[i])


def run_radial(n: float, g: float, photons: int, seed: int = 0, progress=None,
               device: Device | None = None) -> RadialRun:
    """Trace ``photons`` (rounded up to whole :data:`BLOCKS`: :func:`traced_photons`; on a CUDA
    ``device`` as :func:`.radial_cuda.run_radial_cuda` shares them among its streams) into a
    half-space of index ``n`` and anisotropy ``g`` without absorption; ``progress(fraction)``
    after each :data:`CHUNK` blocks (raise from it to cancel; once at the end on a GPU)."""
    if not abs(g) <= MOST_ANISOTROPIC:
        raise TableError(f"a white run is made for |g| <= {MOST_ANISOTROPIC:g}, not g = {g:g}")
    if device is not None and device.is_cuda:
        from .radial_cuda import run_radial_cuda

        run = run_radial_cuda(n, g, photons, seed)
        if progress is not None:
            progress(1.0)
        return run
    start = time.perf_counter()
    per_block = traced_photons(photons) // BLOCKS
    weight = np.zeros((RHO_CELLS, PATH_CELLS))
    rho_sum = np.zeros_like(weight)
    path_sum = np.zeros_like(weight)
    for first in range(0, BLOCKS, CHUNK):
        parts = [np.zeros((CHUNK, RHO_CELLS, PATH_CELLS)) for _ in range(3)]
        _radial_blocks(float(g), float(n), LONGEST / (1.0 - abs(g)), per_block, seed, first, *parts)
        weight += parts[0].sum(axis=0)
        rho_sum += parts[1].sum(axis=0)
        path_sum += parts[2].sum(axis=0)
        if progress is not None:
            progress((first + CHUNK) / BLOCKS)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(weight > 0, rho_sum / weight, 0.0)
        path = np.where(weight > 0, path_sum / weight, 0.0)
    return RadialRun(float(n), float(g), per_block * BLOCKS, weight, rho, path, time.perf_counter() - start)


def radial_path(n: float, g: float, photons: int, seed: int) -> Path:
    """Where the run of these optics lives in the user cache (among the inversion's white
    databases, under their size limit: :mod:`ringlight.core.inversion.white_cache`); a CUDA run
    of as many photons (another sample of the same run) takes the same place."""
    text = json.dumps({"radial": FORMAT_VERSION, "n": float(n), "g": float(g), "photons": int(photons),
                       "seed": int(seed), "ratio": RATIO, "rho": [SHORTEST_RHO, FARTHEST_RHO],
                       "path": [SHORTEST_PATH, LONGEST], "blocks": BLOCKS})
    return white_cache.cache_folder() / f"{hashlib.sha256(text.encode()).hexdigest()[:24]}.npz"


def radial_run(n: float, g: float, photons: int, seed: int = 0, use_cache: bool = True,
               progress=None, device: Device | None = None) -> RadialRun:
    """The run of ``n``, ``g`` from the user cache, or traced (:func:`run_radial`, on ``device``)
    and cached atomically. A damaged cached file is traced again and replaced; something other
    than a regular file in its place is a TableError naming it."""
    path = radial_path(n, g, photons, seed)
    limit = white_cache.cache_limit() if use_cache else 0
    if use_cache:
        try:
            arrays = load_checked(path, path.stem, _ARRAYS)
        except NotAFile as error:
            raise TableError(f"{path}: not a white run of ringlight's ({error}); remove it to rerun") from None
        except DamagedFile:
            arrays = None
        if arrays is not None and (run := _checked_run(arrays, n, g, photons)) is not None:
            white_cache.mark_used(path)
            return run
    run = run_radial(n, g, photons, seed, progress, device)
    if use_cache:
        white_cache.store(path, path.stem, {"photons": np.int64(run.photons), "weight": run.weight, "rho": run.rho,
                                            "path": run.path, "seconds": np.float64(run.seconds)}, limit)
    return run


def traced_photons(photons: int) -> int:
    """The photons a run of ``photons`` traces (rounded up to whole :data:`BLOCKS`, on either device)."""
    return max(1, -(-int(photons) // BLOCKS)) * BLOCKS


def _checked_run(arrays: dict[str, np.ndarray], n: float, g: float, photons: int) -> RadialRun | None:
    """``arrays`` as a run, or None when no run of ``photons`` could have made them."""
    shape = (RHO_CELLS, PATH_CELLS)
    if (arrays["photons"].shape != () or int(arrays["photons"]) != traced_photons(photons)
            or any(arrays[name].shape != shape or arrays[name].dtype != np.float64 for name in ("weight", "rho", "path"))
            or not all(np.isfinite(arrays[name]).all() and arrays[name].min() >= 0 for name in ("weight", "rho", "path"))
            or arrays["seconds"].shape != ()):
        return None
    return RadialRun(float(n), float(g), int(arrays["photons"]), arrays["weight"], arrays["rho"], arrays["path"],
                     float(arrays["seconds"]))
