"""What opening a dataset will take, before it is opened: the response array's size, the memory
budget, whether it opens in memory or out of core, and its store on disk (``ringlight info``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from . import cache
from .disc import disc_offset_count, response_memory_bytes
from .impulse_dataset import WHOLE_READ_BYTES, effective_max_radius, fits_in_memory
from .manifest import Manifest
from .memory import format_bytes, memory_budget
from .response_store import stored_entry_bytes, stored_manifest_key


@dataclass(frozen=True)
class OpenPlan:
    """Sizes in bytes. ``stored`` is the store's size on disk when a current one exists, else None."""

    radius: float
    offsets: int
    response_bytes: int
    budget: int
    location: Path
    stored: int | None

    @property
    def out_of_core(self) -> bool:
        return not fits_in_memory(self.response_bytes, self.budget)

    @property
    def read_band_by_band(self) -> bool:
        """Whether the open reads the responses from the store as they are used: out of core, or a
        reopen of a store larger than :data:`.impulse_dataset.WHOLE_READ_BYTES`."""
        return self.out_of_core or (self.stored is not None and self.response_bytes > WHOLE_READ_BYTES)

    @property
    def memory(self) -> int:
        """About what the open holds: the array and a band's validity flags (at most 1/12 of it) in memory, or
        (read band by band) bands up to the budget."""
        if self.read_band_by_band:
            return min(self.budget, self.response_bytes)
        return self.response_bytes * 13 // 12

    def lines(self) -> list[str]:
        """``ringlight info``'s lines about it."""
        if self.out_of_core:
            where = "out of core: built band by band into its store, read from it"
        elif self.read_band_by_band:
            where = (f"read from its store band by band, as it is over {format_bytes(WHOLE_READ_BYTES)}; "
                     "built in memory at the first open")
        else:
            where = "in memory"
        store = (f"{format_bytes(self.stored)} on disk in {self.location}" if self.stored is not None
                 else f"not built yet (built at the first open, in {self.location})")
        return [f"responses    {format_bytes(self.response_bytes)} at radius {self.radius:.4g} "
                f"({self.offsets} offsets x 3 channels, float32)",
                f"store        {store}",
                f"open memory  about {format_bytes(self.memory)} ({where}; memory budget "
                f"{format_bytes(self.budget)})"]


def plan_open(manifest: Manifest, radius: float | None = None, budget: int | None = None) -> OpenPlan:
    """The :class:`OpenPlan` of :func:`.impulse_dataset.open_dataset` with the same arguments; the
    files are stat'ed only when the dataset's store is of this manifest (:mod:`.cache`)."""
    max_radius = effective_max_radius(manifest, radius)
    offsets = disc_offset_count(max_radius)
    location = cache.cache_location(manifest.folder)
    manifest_key = cache.manifest_key(manifest, max_radius)
    stored = None
    if stored_manifest_key(location) == manifest_key:  # else no file need be stat'ed: nothing is stored
        stored = stored_entry_bytes(location, cache.stat_key(manifest, manifest_key))
    return OpenPlan(max_radius, offsets, response_memory_bytes((manifest.height, manifest.width), max_radius),
                    memory_budget() if budget is None else budget, location, stored)
