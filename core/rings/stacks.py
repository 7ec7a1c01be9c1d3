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
from pathlib import Path

import numba
import numpy as np

from ..dataset.assembly import warm_up_assembly
from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback, disc_offsets
from ..dataset.manifest import Manifest
from ..errors import StackError
from .geometry import ring_geometry, ring_outer_radius
from .members import ring_members, unit_weight_rings

_RADIUS_DECIMALS = 9
MAX_RADII = 10_000
"""Radii a range may hold (a step of 1e-9 asked for 37 GiB of radii before a single image)."""
MAX_RING_REACH = 4096.0
"""Largest ring reach (grid steps) a stack may ask for: far beyond any max_radius a dataset can hold
(the response array grows with its square), and a thickness of 10^5 built a 149 GiB grid of
offsets before the dataset's max_radius was compared."""


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


def radius_range(start: float, stop: float, step: float) -> np.ndarray:
    """Radii ``start, start + step, ...`` up to and including ``stop`` (within 1e-9).

    Examples
    --------
    >>> radius_range(0, 2, 0.5).tolist()
    [0.0, 0.5, 1.0, 1.5, 2.0]
    """
    if not all(math.isfinite(v) for v in (start, stop, step)):
        raise StackError(f"radii {start}:{stop}:{step} must be finite numbers")
    if step <= 0:
        raise StackError(f"radius step must be > 0, got {step}")
    if start < 0 or stop < start:
        raise StackError(f"radii need 0 <= start <= stop, got {start}:{stop}")
    span = (stop - start) / step
    if not span < MAX_RADII:  # infinity too
        raise StackError(f"radii {start:g}:{stop:g}:{step:g} are more than {MAX_RADII}: use a larger step "
                         "or a shorter range")
    count = int(math.floor(span + 1e-9)) + 1
    return np.round(start + step * np.arange(count), _RADIUS_DECIMALS)


def parse_radius_range(text: str) -> np.ndarray:
    """Parse ``"START:STOP:STEP"`` (STOP inclusive) into radii; see :func:`radius_range`."""
    parts = text.split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        start, stop, step = (float(part) for part in parts)
    except ValueError:
        raise StackError(f"radii {text!r} must be START:STOP:STEP, e.g. 1:20:1") from None
    return radius_range(start, stop, step)


def ring_stack(
    dataset: ImpulseDataset,
    radii,
    thickness: float = 1.0,
    antialias: bool = False,
    progress: ProgressCallback | None = None,
    scheduler=None,
) -> Stack:
    """Ring light images E_r for each radius in ``radii`` (grid steps).

    ``scheduler``: None computes here, band by band on every core; a ``dask.distributed.Client``
    or a scheduler's address computes one task per band of the dataset's store on that cluster
    (:mod:`.distributed`), with the same result bit for bit.

    Returns a :class:`Stack` with (len(radii), H, W, 3) float32 images.
    """
    radii = _as_radii(radii)
    check_reach(dataset, radii, 0.0, thickness, antialias)
    images, counts = _ring_images(dataset, radii, thickness, antialias, progress, scheduler)
    return Stack("ring", radii, float(thickness), bool(antialias), dataset.colorspace, images, counts)


def transient_stack(
    dataset: ImpulseDataset,
    radii,
    step: float = 1.0,
    thickness: float = 1.0,
    antialias: bool = False,
    progress: ProgressCallback | None = None,
    scheduler=None,
) -> Stack:
    """Transient images T_r = E_r - E_{r+step} for each radius in ``radii`` (grid steps).

    Each distinct ring radius among ``radii`` and ``radii + step`` is computed once; ``scheduler``
    as :func:`ring_stack` takes it. Returns a :class:`Stack` with (len(radii), H, W, 3) float32 images.
    """
    return ring_and_transient_stacks(dataset, radii, step, thickness, antialias, progress, scheduler)[1]


def ring_and_transient_stacks(
    dataset: ImpulseDataset,
    radii,
    step: float = 1.0,
    thickness: float = 1.0,
    antialias: bool = False,
    progress: ProgressCallback | None = None,
    scheduler=None,
) -> tuple[Stack, Stack]:
    """E_r and T_r = E_r - E_{r+step} for the same ``radii``, sharing every ring: the ring
    light stack's images are views into the computed rings whenever the radii allow it."""
    radii = _as_radii(radii)
    if not math.isfinite(step) or step <= 0:
        raise StackError(f"transient step dr must be > 0, got {step}")
    check_reach(dataset, radii, step, thickness, antialias)
    outer = np.round(radii + step, _RADIUS_DECIMALS)
    unique = np.unique(np.concatenate([radii, outer]))
    images, counts = _ring_images(dataset, unique, thickness, antialias, progress, scheduler)
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


def check_ring_shape(thickness: float, dr: float = 0.0, transient: bool = False) -> None:
    """Raise StackError unless ``thickness`` is finite and > 0 and the transient step ``dr`` is
    finite and >= 0 (> 0 for a ``transient`` stack; 0 adds nothing to a ring light stack's reach)."""
    if not (math.isfinite(dr) and (dr > 0 if transient else dr >= 0)):
        raise StackError(f"transient step dr must be > 0, got {dr}")
    if not (math.isfinite(thickness) and thickness > 0):
        raise StackError(f"ring thickness must be > 0, got {thickness}")


def needed_radius(radii, thickness: float = 1.0, step: float = 0.0, antialias: bool = False) -> float:
    """Largest member distance (grid steps) of the rings a stack over ``radii`` uses: the
    ``radius`` to open a dataset without ``max_radius`` at."""
    check_ring_shape(thickness, step)
    largest = float(_as_radii(radii).max()) + step
    if not largest + thickness / 2.0 <= MAX_RING_REACH:
        raise StackError(f"rings to radius {largest:g} of thickness {thickness:g} reach beyond "
                         f"{MAX_RING_REACH:g} grid steps, more than any dataset holds")
    if antialias:
        return ring_geometry(largest, thickness, antialias).outer_radius
    return ring_outer_radius(largest, thickness)  # not the ring itself: 2.3 GB at radius 4000


def check_reach(dataset: ImpulseDataset, radii, step: float = 0.0, thickness: float = 1.0,
                antialias: bool = False) -> None:
    """Raise StackError, naming the dataset and the radii that would work, when a ring of
    ``radii`` (or, for a transient ``step`` > 0, of ``radii + step``) reaches beyond the
    dataset's ``max_radius`` (grid steps)."""
    check_reach_within(dataset.manifest.folder, dataset.max_radius, radii, step, thickness, antialias)


def check_reach_within(folder, max_radius: float, radii, step: float = 0.0, thickness: float = 1.0,
                       antialias: bool = False) -> None:
    """:func:`check_reach` for the dataset in ``folder`` of ``max_radius``, before it is opened."""
    radii = _as_radii(radii)
    limit = max_radius + 1e-9
    if needed_radius(radii, thickness, step, antialias) <= limit:
        return

    def reach(radius: float) -> float:
        return needed_radius([radius], thickness, step, antialias)

    # The reach grows with the radius: bisect the sorted radii for the last one that fits
    # (a few ring geometries, where testing each of up to 10 000 radii could take minutes).
    ordered = np.unique(radii)
    low, high = -1, len(ordered) - 1  # ordered[high] does not fit; ordered[low] does (or none)
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (middle, high) if reach(ordered[middle]) <= limit else (low, middle)
    beyond = float(ordered[high])
    kind = f"transient radii (dr {step:g})" if step > 0 else "ring radii"
    if low >= 0:
        best = float(ordered[low])
        spacing = float(radii[1] - radii[0]) if len(radii) > 1 else 0.0
        regular = spacing > 0 and np.allclose(np.diff(radii), spacing)
        suggestion = f"{kind} up to {best:g} work" + (f" (radii {radii[0]:g}:{best:g}:{spacing:g})" if regular else "")
    else:
        suggestion = f"no {kind} of those requested work"
    raise StackError(
        f"{folder}: the ring of radius {beyond + step:g} (thickness {thickness:g}) reaches "
        f"{reach(beyond):.3f} grid steps, beyond the dataset's max_radius {max_radius:g}; {suggestion}"
    )


def ring_weight_matrix(dataset: ImpulseDataset, radii, thickness: float = 1.0, antialias: bool = False) -> np.ndarray:
    """Ring weights over the dataset's offset axis: (len(radii), K) float64.

    Row ``i`` holds the weight of each offset ``dataset.offsets[k]`` in the ring of radius
    ``radii[i]`` (0 outside it), so that for one point ``p = (y, x)``::

        w = matrix * dataset.validity_rows(y, y + 1)[0, x]   # drop missing and outside lit points
        E = (w @ dataset.point(y, x)) / w.sum(1)        # (n, 3): E_r(p) for every radius
    """
    radii = _as_radii(radii)
    first, stop, weight_start, weights = _ring_tables(dataset, radii, thickness, antialias)
    matrix = np.zeros((len(radii), len(dataset.offsets)))
    for row in range(len(radii)):
        matrix[row, first[row]:stop[row]] = weights[weight_start[row]:weight_start[row + 1]]
    return matrix


def _as_radii(radii) -> np.ndarray:
    radii = np.atleast_1d(np.asarray(radii, np.float64))
    if radii.ndim != 1 or radii.size == 0:
        raise StackError("a stack needs at least one radius")
    if not np.isfinite(radii).all() or (radii < 0).any():
        raise StackError("ring radii must be finite and >= 0")
    if radii.max() > MAX_RING_REACH:  # before rounding: 1e308 overflowed in it
        raise StackError(f"ring radius {radii.max():g} reaches beyond {MAX_RING_REACH:g} grid steps, "
                         "more than any dataset holds")
    return np.round(radii, _RADIUS_DECIMALS)


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


def _ring_images(dataset, radii, thickness, antialias, progress, scheduler=None):
    tables = _ring_tables(dataset, radii, thickness, antialias)
    if scheduler is not None:
        from .distributed import distributed_ring_images

        return distributed_ring_images(dataset, tables, scheduler, progress)
    height, width = dataset.grid_shape
    images = np.empty((len(radii), height, width, 3), np.float32)
    counts = np.empty((len(radii), height, width), np.int32)
    lit = dataset.lit
    for row0, row1 in dataset.bands():
        band_images(dataset.rows(row0, row1), lit, dataset.observed, dataset.offsets, tables, row0,
                    images[:, row0:row1], counts[:, row0:row1])
        if progress is not None:
            progress(row1 / height)
    return images, counts


def band_images(responses: np.ndarray, lit: np.ndarray, observed: np.ndarray, offsets: np.ndarray, tables: tuple,
                row0: int, images: np.ndarray, counts: np.ndarray) -> None:
    """Ring images of the band of grid rows from ``row0``: fill ``images`` (n, rows, W, 3) float32 and
    ``counts`` (n, rows, W) int32 from its ``responses`` (rows, W, K, 3), the (H, W) bool ``lit`` and
    ``observed`` points, the (K, 2) ``offsets`` and the rings' ``tables`` (:func:`_ring_tables`)."""
    first, stop, weight_start, weights = tables
    unweighted = unit_weight_rings(tables)
    counts[...], totals = ring_members(lit, observed, offsets, tables, unweighted, row0, row0 + len(responses))
    _ring_sums(np.ascontiguousarray(responses), first, stop, weight_start, weights, unweighted, counts, totals,
               images)


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
                if counts[j, y, x] == 0:
                    images[j, y, x, 0] = np.nan
                    images[j, y, x, 1] = np.nan
                    images[j, y, x, 2] = np.nan
                else:
                    total = totals[j, y, x]
                    images[j, y, x, 0] = s0 / total
                    images[j, y, x, 1] = s1 / total
                    images[j, y, x, 2] = s2 / total


def warm_up_kernels() -> None:
    """Load the compiled kernels once on tiny arrays.

    Numba's first dispatch in a process sets up its typing context while holding the GIL for
    about 0.1 s; an application calls this at start-up so that the first dataset opened in a
    worker thread does not freeze its GUI thread for that long.
    """
    offsets = disc_offsets(1.0)
    manifest = Manifest(
        folder=Path("."), height=1, width=1, pitch_mm=None, colorspace="sRGB", frame_space="grid", mapping=None,
        max_radius=1.0, frames=(), dark=None, ground_truth=None, notes=None,
    )
    dataset = ImpulseDataset(manifest, 1.0, offsets, np.zeros((1, 1, len(offsets), 3), np.float32),
                             np.ones((1, 1), np.int32), np.ones((1, 1), bool))
    ring_stack(dataset, [0.0])
    warm_up_assembly()
