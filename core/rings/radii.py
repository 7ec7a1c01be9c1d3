"""Ring radii and how far their rings reach: ranges of radii, their checks, and whether a
dataset's ``max_radius`` holds the rings a stack over them uses (radii in grid steps)."""

from __future__ import annotations

import math

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..errors import StackError
from .geometry import ring_geometry, ring_outer_radius

RADIUS_DECIMALS = 9
"""Decimals radii are rounded to, so that r and r + dr of two requests meet exactly."""
MAX_RADII = 10_000
"""Radii a range may hold (a step of 1e-9 asked for 37 GiB of radii before a single image)."""
MAX_RING_REACH = 4096.0
"""Largest ring reach (grid steps) a stack may ask for: far beyond any max_radius a dataset can hold
(the response array grows with its square), and a thickness of 10^5 built a 149 GiB grid of
offsets before the dataset's max_radius was compared."""



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
    if stop > MAX_RING_REACH:  # before the arithmetic: 1e308 overflowed in the rounding
        raise StackError(f"ring radius {stop:g} reaches beyond {MAX_RING_REACH:g} grid steps, "
                         "more than any dataset holds")
    span = (stop - start) / step
    if not span < MAX_RADII:  # infinity too
        raise StackError(f"radii {start:g}:{stop:g}:{step:g} are more than {MAX_RADII}: use a larger step "
                         "or a shorter range")
    count = int(math.floor(span + 1e-9)) + 1
    return np.round(start + step * np.arange(count), RADIUS_DECIMALS)


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
    largest = float(as_radii(radii).max()) + step
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
    radii = as_radii(radii)
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


def as_radii(radii) -> np.ndarray:
    """(n,) float64 radii, checked (at least one, finite, >= 0, within MAX_RING_REACH) and rounded
    to RADIUS_DECIMALS; StackError otherwise."""
    radii = np.atleast_1d(np.asarray(radii, np.float64))
    if radii.ndim != 1 or radii.size == 0:
        raise StackError("a stack needs at least one radius")
    if not np.isfinite(radii).all() or (radii < 0).any():
        raise StackError("ring radii must be finite and >= 0")
    if radii.max() > MAX_RING_REACH:  # before rounding: 1e308 overflowed in it
        raise StackError(f"ring radius {radii.max():g} reaches beyond {MAX_RING_REACH:g} grid steps, "
                         "more than any dataset holds")
    return np.round(radii, RADIUS_DECIMALS)
