"""Ring light and transient image stacks for every grid point (the definitions of the dataset
format, ``docs/format/dataset.md``)::

    E_r(p) = sum_q w_q I_q(p) / sum_q w_q   over ring members q = p + d that are in the grid
                                            and lit (weights 1 for the default ring)
    T_r(p) = E_r(p) - E_{r+dr}(p)           # paper Eq. 8: bounds path length to [r, r+dr)

Every distinct ring radius is computed once, so E_{r+dr} of one transient is shared with E_r
of the next. The sums run in one compiled pass over the response array.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback
from ..dataset.warm_up import warm_up_assembly, warm_up_dataset
from ..device import Device
from ..errors import StackError
from ..kernel_cache import is_cached
from .geometry import ring_geometry, ring_outer_radius
from .members import ring_members, unit_weight_rings
from .radii import RADIUS_DECIMALS, as_radii, check_reach


@dataclass(frozen=True, eq=False)
class Stack:
    """A computed stack of ring light (``kind="ring"``) or transient (``"transient"``) images.

    Attributes
    ----------
    radii
        (n,) float64 ring radii in grid steps.
    images
        (n, H, W, 3) float32 linear radiance in ``colorspace``; NaN where undefined (no ring
        member, or for a transient, either ring lacking members; unobserved points).
    counts
        (n, H, W) int32: ring members that contributed to E_r at each point.
    outer_counts
        (n, H, W) int32 members behind E_{r+step} (transient stacks), else None.
    step
        dr of a transient stack in grid steps, else None.
    """

    kind: str
    radii: np.ndarray
    thickness: float
    antialias: bool
    colorspace: str
    images: np.ndarray
    counts: np.ndarray
    outer_counts: np.ndarray | None = None
    step: float | None = None


def ring_stack(
    dataset: ImpulseDataset,
    radii,
    thickness: float = 1.0,
    antialias: bool = False,
    progress: ProgressCallback | None = None,
    scheduler=None,
    device: Device | None = None,
) -> Stack:
    """Ring light images E_r for each radius in ``radii`` (grid steps).

    ``scheduler``: None computes here, band by band on every core; a ``dask.distributed.Client``
    or a scheduler's address computes one task per band of the dataset's store on that cluster
    (:mod:`.distributed`), with the same result bit for bit. ``device``: a CUDA device sums the
    rings on the GPU (:mod:`.stack_cuda`; the same to float rounding), None or the CPU here.

    Returns a :class:`Stack` with (len(radii), H, W, 3) float32 images.
    """
    radii = as_radii(radii)
    check_reach(dataset, radii, 0.0, thickness, antialias)
    images, counts = _ring_images(dataset, radii, thickness, antialias, progress, scheduler, device)
    return Stack("ring", radii, float(thickness), bool(antialias), dataset.colorspace, images, counts)


def transient_stack(
    dataset: ImpulseDataset,
    radii,
    step: float = 1.0,
    thickness: float = 1.0,
    antialias: bool = False,
    progress: ProgressCallback | None = None,
    scheduler=None,
    device: Device | None = None,
) -> Stack:
    """Transient images T_r = E_r - E_{r+step} for each radius in ``radii`` (grid steps).

    Each distinct ring radius among ``radii`` and ``radii + step`` is computed once; ``scheduler``
    and ``device`` as :func:`ring_stack` takes them. Returns a :class:`Stack` with (len(radii), H, W, 3)
    float32 images.
    """
    return ring_and_transient_stacks(dataset, radii, step, thickness, antialias, progress, scheduler, device)[1]


def ring_and_transient_stacks(
    dataset: ImpulseDataset,
    radii,
    step: float = 1.0,
    thickness: float = 1.0,
    antialias: bool = False,
    progress: ProgressCallback | None = None,
    scheduler=None,
    device: Device | None = None,
) -> tuple[Stack, Stack]:
    """E_r and T_r = E_r - E_{r+step} for the same ``radii``, sharing every ring: the ring
    light stack's images are views into the computed rings whenever the radii allow it."""
    radii = as_radii(radii)
    if not math.isfinite(step) or step <= 0:
        raise StackError(f"transient step dr must be > 0, got {step}")
    check_reach(dataset, radii, step, thickness, antialias)
    outer = np.round(radii + step, RADIUS_DECIMALS)
    unique = np.unique(np.concatenate([radii, outer]))
    images, counts = _ring_images(dataset, unique, thickness, antialias, progress, scheduler, device)
    inner = _as_selection(np.searchsorted(unique, radii))
    outer = _as_selection(np.searchsorted(unique, outer))
    ring = Stack("ring", radii, float(thickness), bool(antialias), dataset.colorspace, images[inner], counts[inner])
    transient = Stack(
        "transient", radii, float(thickness), bool(antialias), dataset.colorspace, images[inner] - images[outer],
        counts[inner], counts[outer], float(step),
    )
    return ring, transient


def _as_selection(index: np.ndarray) -> slice | np.ndarray:
    """A slice (a view, no copy) when ``index`` is a run of consecutive integers."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


def ring_weight_matrix(dataset: ImpulseDataset, radii, thickness: float = 1.0, antialias: bool = False) -> np.ndarray:
    """Ring weights over the dataset's offset axis: (len(radii), K) float64.

    Row ``i`` holds the weight of each offset ``dataset.offsets[k]`` in the ring of radius
    ``radii[i]`` (0 outside it), so that for one point ``p = (y, x)``::

        w = matrix * dataset.validity_rows(y, y + 1)[0, x]   # drop missing and outside lit points
        E = (w @ dataset.point(y, x)) / w.sum(1)        # (n, 3): E_r(p) for every radius
    """
    radii = as_radii(radii)
    first, stop, weight_start, weights = _ring_tables(dataset, radii, thickness, antialias)
    matrix = np.zeros((len(radii), len(dataset.offsets)))
    for row in range(len(radii)):
        matrix[row, first[row]:stop[row]] = weights[weight_start[row]:weight_start[row + 1]]
    return matrix


def _ring_tables(dataset: ImpulseDataset, radii: np.ndarray, thickness: float, antialias: bool):
    """Each ring as a contiguous run ``[first, stop)`` of the dataset's offset axis with a
    weight per offset of the run (0 for offsets of the run outside the ring).

    Offsets are ordered by distance, so a default ring is exactly one run and an anti-aliased
    ring a run slightly wider than its members. Returns ``(first, stop, weight_start, weights)``.
    """
    reach = int(np.abs(dataset.offsets).max(initial=0))
    lookup = np.full((2 * reach + 1, 2 * reach + 1), -1, np.int64)
    lookup[dataset.offsets[:, 0] + reach, dataset.offsets[:, 1] + reach] = np.arange(len(dataset.offsets))
    first, stop, weight_start, weights = [], [], [0], []
    for radius in radii:
        try:
            # Refused before the ring is built: --thickness 4000 built 1.4 GB of it first.
            if (least := ring_outer_radius(float(radius), thickness)) > dataset.max_radius:
                raise StackError(
                    f"the ring of radius {radius:g} (thickness {thickness:g}) reaches {least:.3f} "
                    f"grid steps, beyond the dataset's max_radius {dataset.max_radius:g}")
            ring = ring_geometry(float(radius), thickness, antialias)
        except ValueError as error:
            raise StackError(str(error)) from None
        dy, dx = ring.offsets[:, 0], ring.offsets[:, 1]
        within = (np.abs(dy) <= reach) & (np.abs(dx) <= reach)
        index = np.full(len(dy), -1, np.int64)
        index[within] = lookup[dy[within] + reach, dx[within] + reach]
        if (index < 0).any():
            raise StackError(
                f"the ring of radius {radius:g} (thickness {thickness:g}) reaches {ring.outer_radius:.3f} "
                f"grid steps, beyond the dataset's max_radius {dataset.max_radius:g}"
            )
        # A ring of no grid offsets (radius 0.5, thickness 0.5) is an empty run: no member, NaN.
        low, high = (int(index.min()), int(index.max()) + 1) if len(index) else (0, 0)
        run = np.zeros(high - low)
        run[index - low] = ring.weights
        first.append(low)
        stop.append(high)
        weights.append(run)
        weight_start.append(weight_start[-1] + len(run))
    return (np.asarray(first, np.int64), np.asarray(stop, np.int64),
            np.asarray(weight_start, np.int64), np.concatenate(weights))


def _ring_images(dataset, radii, thickness, antialias, progress, scheduler=None, device=None):
    tables = _ring_tables(dataset, radii, thickness, antialias)
    if scheduler is not None:
        from .distributed import distributed_ring_images

        return distributed_ring_images(dataset, tables, scheduler, progress)
    height, width = dataset.grid_shape
    images = np.empty((len(radii), height, width, 3), np.float32)
    counts = np.empty((len(radii), height, width), np.int32)
    lit = dataset.lit
    sums = _ring_sums
    if device is not None and device.is_cuda:
        from .stack_cuda import cuda_ring_sums as sums
    for row0, row1 in dataset.bands():
        band_images(dataset.rows(row0, row1), lit, dataset.observed, dataset.offsets, tables, row0,
                    images[:, row0:row1], counts[:, row0:row1], sums)
        if progress is not None:
            progress(row1 / height)
    return images, counts


def band_images(responses: np.ndarray, lit: np.ndarray, observed: np.ndarray, offsets: np.ndarray, tables: tuple,
                row0: int, images: np.ndarray, counts: np.ndarray, sums=None) -> None:
    """Ring images of the band of grid rows from ``row0``: fill ``images`` (n, rows, W, 3) float32 and
    ``counts`` (n, rows, W) int32 from its ``responses`` (rows, W, K, 3), the (H, W) bool ``lit`` and
    ``observed`` points, the (K, 2) ``offsets`` and the rings' ``tables`` (:func:`_ring_tables`);
    ``sums`` the kernel that sums the rings (:func:`_ring_sums`, or the GPU's
    :func:`.stack_cuda.cuda_ring_sums`)."""
    first, stop, weight_start, weights = tables
    unweighted = unit_weight_rings(tables)
    counts[...], totals = ring_members(lit, observed, offsets, tables, unweighted, row0, row0 + len(responses))
    (sums or _ring_sums)(np.ascontiguousarray(responses), first, stop, weight_start, weights, unweighted, counts, totals,
               images)


def store_mean(images, j, y, x, count, total, s0, s1, s2):
    """``images[j, y, x]`` = the ring's sums ``s0, s1, s2`` over its members' ``total`` weight;
    NaN when it has no member (``count`` 0). Compiled for the CPU's kernel and the GPU's
    (:mod:`.stack_cuda`)."""
    if count == 0:
        images[j, y, x, 0] = math.nan
        images[j, y, x, 1] = math.nan
        images[j, y, x, 2] = math.nan
    else:
        images[j, y, x, 0] = s0 / total
        images[j, y, x, 1] = s1 / total
        images[j, y, x, 2] = s2 / total


_store_mean = numba.njit(cache=True, inline="always")(store_mean)

LANES = 12
"""Partial sums kept while a default ring is summed (a multiple of 3): four offsets' R, G, B, which
a compiler holds in vector registers (a pixel's responses are interleaved R, G, B, so a sum per
channel over them is a strided read that it vectorises poorly)."""


@numba.njit(parallel=True, cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _ring_sums(responses, first, stop, weight_start, weights, unweighted, counts, totals, images):
    """images[j, y, x] = the weighted sum of ring j's responses at (y, x) / totals[j, y, x], NaN
    where counts[j, y, x] is 0; ``responses`` (rows, W, K, 3) C-contiguous, ``counts`` and
    ``totals`` the ring members' count and weight (:func:`.members.ring_members`), ``unweighted``
    (n,) bool the rings whose run holds weights of 1 only.

    Each ring reads one contiguous run of a pixel's responses (invalid responses are 0 by the
    dataset's invariant, so only the denominator needs to know the members); reassociation lets
    the compiler vectorise the sums. A ring whose run holds weights of 1 only (every default ring)
    is summed without them, over the run's interleaved R, G, B values as one flat run in
    :data:`LANES` partial sums (lane ``l`` holds channel ``l % 3``): on the stack benchmark's rings
    27.6 -> 16.4 ms against a read of the whole array in 9.4 ms (a sum per channel with weights
    took 1.6x longer still), and 12.0-12.5 ms once the members were counted apart (1.2 ms).
    """
    rows, width, offsets = responses.shape[0], responses.shape[1], responses.shape[2]
    flat = responses.reshape(rows, width, offsets * 3)
    for y in numba.prange(rows):
        lanes = np.empty(LANES)
        for x in range(width):
            pixel = flat[y, x]
            for j in range(first.size):
                if unweighted[j]:
                    start = 3 * first[j]
                    end = 3 * stop[j]
                    whole = start + (end - start) // LANES * LANES
                    lanes[:] = 0.0
                    for i in range(start, whole, LANES):
                        for lane in range(LANES):
                            lanes[lane] += pixel[i + lane]
                    s0 = 0.0
                    s1 = 0.0
                    s2 = 0.0
                    for lane in range(0, LANES, 3):
                        s0 += lanes[lane]
                        s1 += lanes[lane + 1]
                        s2 += lanes[lane + 2]
                    for i in range(whole, end, 3):
                        s0 += pixel[i]
                        s1 += pixel[i + 1]
                        s2 += pixel[i + 2]
                else:
                    s0 = 0.0
                    s1 = 0.0
                    s2 = 0.0
                    shift = weight_start[j] - first[j]
                    for k in range(first[j], stop[j]):
                        w = weights[shift + k]
                        s0 += w * pixel[3 * k]
                        s1 += w * pixel[3 * k + 1]
                        s2 += w * pixel[3 * k + 2]
                _store_mean(images, j, y, x, counts[j, y, x], totals[j, y, x], s0, s1, s2)


def kernels_compiled() -> bool:
    """Whether numba's cache holds the stack's kernel already. False on a fresh install's first
    start: opening a dataset then compiles ringlight's kernels first, side by side
    (:mod:`ringlight.core.compile_ahead`: half a minute on two cores), once; later starts load them
    from the cache in about a second. Looks for the index file numba
    names after the function (``stacks._ring_sums-<line>.py<version>.nbi``) in its cache folder
    (:func:`ringlight.core.kernel_cache.is_cached`); True where numba caches nothing."""
    return is_cached(_ring_sums)


def warm_up_kernels() -> None:
    """Load the compiled kernels once on tiny arrays: the stack's (:func:`warm_up_stack`) and an
    open's (:func:`ringlight.core.dataset.warm_up.warm_up_assembly`).

    Numba's first dispatch in a process sets up its typing context while holding the GIL for
    about 0.1 s; an application calls this at start-up so that the first dataset opened in a
    worker thread does not freeze its GUI thread for that long.
    """
    warm_up_stack()
    warm_up_assembly()


def warm_up_stack() -> None:
    """Load the kernels of a ring stack (its members' counts, its rings' sums, into a whole stack's
    images and into a band of them) and of the responses' validity flags, on a 2 x 1 dataset."""
    dataset = warm_up_dataset()
    ring_stack(dataset, [0.0])
    images, counts = np.zeros((2, 3, 1, 3), np.float32), np.zeros((2, 3, 1), np.int32)
    band_images(dataset.rows(0, 2), dataset.lit, dataset.observed, dataset.offsets,
                _ring_tables(dataset, np.array([0.0, 1.0]), 1.0, False), 0, images[:, :2], counts[:, :2])  # not contiguous
    dataset.validity_rows(0, 2)
