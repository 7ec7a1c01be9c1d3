"""A stack computation as a frozen request: every input captured, runnable in a worker.

The explorer shows ring light images E_r and transient images T_r = E_r - E_{r+dr} of the same
radii and switches between them without recomputing, so a request yields both, sharing each
distinct ring radius (the rings at r + dr are the transient's outer rings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset, ProgressCallback
from ..device import Device
from ..errors import StackError
from .radii import check_ring_shape, needed_radius, radius_range
from .stacks import Stack, ring_and_transient_stacks


@dataclass(frozen=True)
class StackRequest:
    """Radii ``start, start + step, ..., stop`` (grid steps, stop inclusive), transient step
    ``dr``, ring ``thickness`` and anti-aliasing."""

    start: float = 0.0
    stop: float = 10.0
    step: float = 1.0
    dr: float = 1.0
    thickness: float = 1.0
    antialias: bool = False

    def radii(self) -> np.ndarray:
        """(n,) float64 radii; raises StackError for a bad range."""
        return radius_range(self.start, self.stop, self.step)

    def reach(self) -> float:
        """Largest lit-point distance (grid steps) the request's rings use."""
        return needed_radius(self.radii(), self.thickness, self.dr, self.antialias)

    def check_rings(self) -> None:
        """Raise StackError unless the radius step, dr and thickness are finite and > 0 and the
        first radius finite and >= 0."""
        if not (math.isfinite(self.start) and self.start >= 0):
            raise StackError(f"the first radius must be >= 0, got {self.start}")
        if not (math.isfinite(self.step) and self.step > 0):
            raise StackError(f"radius step must be > 0, got {self.step}")
        check_ring_shape(self.thickness, self.dr, transient=True)

    def check(self, dataset: ImpulseDataset) -> None:
        """Raise StackError when ``dataset`` cannot serve the request."""
        self.check_rings()
        if self.reach() > dataset.max_radius + 1e-9:
            raise StackError(
                f"radii up to {self.stop:g} + dr {self.dr:g} (thickness {self.thickness:g}) reach "
                f"{self.reach():.2f} grid steps, beyond the dataset's max_radius {dataset.max_radius:g}; "
                f"the largest stop is {largest_stop(dataset.max_radius, self):g}"
            )

    def with_changes(self, **changes) -> "StackRequest":
        return replace(self, **changes)


@dataclass(frozen=True, eq=False)
class StackPair:
    """Ring light and transient stacks of one request (same radii, counts shared)."""

    request: StackRequest
    ring: Stack
    transient: Stack

    @property
    def radii(self) -> np.ndarray:
        return self.ring.radii


def largest_stop(max_radius: float, request: StackRequest) -> float:
    """Largest ``stop`` on the request's radius grid whose rings stay within ``max_radius``;
    ``request.start`` when even that does not fit. Raises StackError for a step, dr or thickness
    that is not finite and > 0 (a step of 0 looped for good)."""
    request.check_rings()

    def radius(steps: int) -> float:
        return round(request.start + steps * request.step, 9)

    def fits(steps: int) -> bool:
        return needed_radius([radius(steps)], request.thickness, request.dr, request.antialias) <= max_radius + 1e-9

    if not fits(1):
        return request.start
    # The reach grows with the radius: double the steps until they do not fit, then bisect.
    low, high = 1, 2
    while fits(high):
        low, high = high, 2 * high
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (middle, high) if fits(middle) else (low, middle)
    return radius(low)


def default_request(max_radius: float, most_radii: int = 64) -> StackRequest:
    """Radii 0, 1, ... as far as ``max_radius`` allows (at most ``most_radii``), dr 1, w 1."""
    request = StackRequest(start=0.0, stop=0.0)
    return request.with_changes(stop=min(largest_stop(max_radius, request), float(most_radii - 1)))


def compute_stacks(dataset: ImpulseDataset, request: StackRequest,
                   progress: ProgressCallback | None = None, device: Device | None = None) -> StackPair:
    """E_r and T_r = E_r - E_{r+dr} for every radius of ``request``; each ring computed once, its
    rings summed on ``device`` (the CPU when None, and for an antialiased request, which the
    GPU's gather does not sum: as ``ringlight stack --interpolate``)."""
    request.check(dataset)
    ring, transient = ring_and_transient_stacks(
        dataset, request.radii(), request.dr, request.thickness, request.antialias, progress,
        device=None if request.antialias else device,
    )
    return StackPair(request, ring, transient)
