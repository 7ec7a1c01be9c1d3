"""What a user gives a layer inversion: :class:`InversionSettings`, checked, and read from typed text
(the CLI's options, the Layers tab's fields)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..dataset.sample import Sample
from ..device import CHOICES
from ..errors import RinglightError

SEARCH_BINS = 9
"""Depth bins of a searched structure: 8 of one grid step, then the base."""
MUS_GRID = (0.25, 0.5, 1.0, 2.0, 4.0)
"""Common scattering coefficients (per grid step) tried when none is given."""
N_GRID = (1.0, 1.33, 1.4, 1.5)
"""Refractive indices tried when neither the user nor the dataset gives one: index-matched (or a
rough surface), water, skin and tissue, plastics and glass."""
DEFAULT_G = 0.0
"""Anisotropy assumed when neither the user nor the dataset gives one."""
MAX_LAYERS = 4
DEFAULT_PHOTONS = 20_000
DEFAULT_FINAL_PHOTONS = 1_000_000
"""Photons of the white run each fitted structure gets at the end (:mod:`.white_cells`), tallied in
cells (60-80 MB on disk for three layers; records would take 1.5 GB). At 200 000 the run's own noise at
the outer rings, where light that reaches them is carried by few long paths, ranked a wrong
structure first on a held-out slab (boundaries [2, 4] at chi-square 23.7 against the truth's
[2, 5] at 40.3 for 27 degrees of freedom, the middle layer 0.014 off in xy); at 1 000 000 the truth
fits best (24.5 against 37.7) and its layers are 0.0004 and 0.0005 off."""
FINAL_PHOTON_RANGE = (1000, 10_000_000)
PHOTON_RANGE = (1000, 1_000_000)
"""Photons of a white database a user may ask for: a 20 000-photon database holds 14-43 MB, and a
search keeps a quarter of dozens of them (0.89 GB of peak RSS searching layers3 at the default)."""
MAX_MUS = 100.0
"""Largest scattering coefficient (per grid step) a database is run for: a walk's scattering events
grow with mus x depth (about 10^5 per photon at this bound over the default depth), and light that
spreads over a small part of a grid step says nothing about the layers' colours (measure at a finer
grid instead)."""
DEFAULT_DEPTH = 64.0
MAX_DEPTH = 1024.0
"""Deepest modelled slab (grid steps): the white walk has no absorption, so its length grows with
the depth (``--depth 1000000`` ran for minutes of CPU per database), and light returning from
far below the rings' reach says nothing about the layers the rings see."""


class InversionError(RinglightError):
    """An inversion cannot be set up (bad settings or too little signal)."""


@dataclass(frozen=True)
class InversionSettings:
    """What the user gives.

    Attributes
    ----------
    layers
        Number of layers, or None to compare 1 .. MAX_LAYERS by BIC.
    boundaries
        Depths (whole grid steps, increasing, > 0) where layers meet; None to search them.
    mus
        One common scattering coefficient, one per layer (boundaries then needed), or None to
        choose a common one from :data:`MUS_GRID`; per grid step.
    n
        Refractive index; None to choose it from :data:`N_GRID` by chi-square (as the scattering).
        A dataset that states its sample's index (the manifest's ``sample.n``) gives it instead:
        :meth:`for_dataset`.
    g
        Henyey-Greenstein anisotropy; None for the dataset's ``sample.g``, else :data:`DEFAULT_G`.
    depth
        Thickness of the modelled slab, grid steps (light below is lost).
    photons
        Photons of each white database a search compares structures with (records).
    final_photons
        Photons of the white run of each structure fitted at the end (tallied in cells).
    device
        Where the white runs go: ``"cpu"``, ``"cuda"`` or ``"auto"``
        (:func:`ringlight.core.device.choose_device`).
    """

    layers: int | None = None
    boundaries: tuple[int, ...] | None = None
    mus: float | tuple[float, ...] | None = None
    n: float | None = None
    g: float | None = None
    depth: float = DEFAULT_DEPTH
    photons: int = DEFAULT_PHOTONS
    final_photons: int = DEFAULT_FINAL_PHOTONS
    device: str = "cpu"

    def check(self) -> None:
        """Raise :class:`InversionError` naming the first setting that cannot work."""
        if self.device not in CHOICES:
            raise InversionError(f"device must be one of {', '.join(CHOICES)}, got {self.device!r}")
        if self.boundaries is not None and not all(isinstance(b, (int, np.integer)) for b in self.boundaries):
            raise InversionError(f"layer boundaries must be whole grid steps, got {self.boundaries}")
        if self.mus is not None and not isinstance(self.mus, (int, float, np.number, tuple)):
            raise InversionError(f"mus must be one number or a tuple of one per layer, got {self.mus!r}")
        if not PHOTON_RANGE[0] <= self.photons <= PHOTON_RANGE[1]:
            raise InversionError(f"photons must be {PHOTON_RANGE[0]} to {PHOTON_RANGE[1]}, got {self.photons}")
        if not FINAL_PHOTON_RANGE[0] <= self.final_photons <= FINAL_PHOTON_RANGE[1]:
            raise InversionError(f"final photons must be {FINAL_PHOTON_RANGE[0]} to {FINAL_PHOTON_RANGE[1]}, "
                                 f"got {self.final_photons}")
        if self.layers is not None and not 1 <= self.layers <= MAX_LAYERS:
            raise InversionError(f"layers must be 1..{MAX_LAYERS} or auto, got {self.layers}")
        if self.boundaries is not None:
            bounds = list(self.boundaries)
            if any(b <= 0 for b in bounds) or bounds != sorted(set(bounds)) or bounds and bounds[-1] >= self.depth:
                raise InversionError(f"layer boundaries must increase from above 0 to below the depth "
                                     f"{self.depth:g}, got {', '.join(map(str, bounds))}")
            if len(bounds) >= MAX_LAYERS:
                raise InversionError(f"at most {MAX_LAYERS} layers ({MAX_LAYERS - 1} boundaries), got "
                                     f"{len(bounds)} boundaries")
            if self.layers is not None and len(bounds) != self.layers - 1:
                raise InversionError(f"{self.layers} layers need {self.layers - 1} boundaries, got {len(bounds)}")
        if isinstance(self.mus, tuple):
            if self.boundaries is None:
                raise InversionError("a scattering coefficient per layer needs the layer boundaries too")
            if len(self.mus) != len(self.boundaries) + 1:
                raise InversionError(f"{len(self.boundaries) + 1} layers need {len(self.boundaries) + 1} "
                                     f"scattering coefficients, got {len(self.mus)}")
        if self.mus is not None and not all(0 < m <= MAX_MUS for m in np.atleast_1d(self.mus)):
            raise InversionError(f"scattering coefficients must be > 0 and at most {MAX_MUS:g} per grid step, "
                                 f"got {', '.join(f'{m:g}' for m in np.atleast_1d(self.mus))}")
        if not math.isfinite(self.depth) or self.depth < SEARCH_BINS + 1:
            raise InversionError(f"the modelled depth must be at least {SEARCH_BINS + 1} grid steps, got {self.depth:g}")
        if self.depth > MAX_DEPTH:
            raise InversionError(f"the modelled depth must be at most {MAX_DEPTH:g} grid steps (a deeper slab only "
                                 f"lengthens the walks: light from below does not reach the rings), got {self.depth:g}")
        if self.n is not None and not 1.0 <= self.n <= 3.0:
            raise InversionError(f"the refractive index must be in [1, 3], got {self.n:g}")
        if self.g is not None and not -1.0 < self.g < 1.0:
            raise InversionError(f"the anisotropy g must be in (-1, 1), got {self.g:g}")

    @property
    def anisotropy(self) -> float:
        """``g``, or :data:`DEFAULT_G` when none is given."""
        return DEFAULT_G if self.g is None else self.g

    @property
    def indices(self) -> tuple[float, ...]:
        """The refractive indices a fit tries: ``n``, or every one of :data:`N_GRID`."""
        return N_GRID if self.n is None else (self.n,)

    def for_dataset(self, sample: Sample) -> "InversionSettings":
        """These settings with what the dataset states of its surface (``sample``, the manifest's
        ``sample`` key) where the user gave nothing: the user's values win."""
        return replace(self, n=self.n if self.n is not None else sample.n,
                       g=self.g if self.g is not None else sample.g)


def settings_from_text(layers: str, boundaries: str, mus: str, n: float | None, g: float | None,
                       depth: float = DEFAULT_DEPTH, photons: int = DEFAULT_PHOTONS,
                       final_photons: int = DEFAULT_FINAL_PHOTONS) -> InversionSettings:
    """Settings from what a user typed (the CLI's options, the Layers tab's fields): ``layers``
    "auto" or a count, ``boundaries`` and ``mus`` comma-separated numbers or empty for the
    defaults, ``n`` and ``g`` None for the dataset's or the search's; checked
    (:class:`InversionError` naming the setting)."""
    def numbers(text, kind, name):
        try:
            return tuple(kind(part) for part in text.split(","))
        except ValueError:
            raise InversionError(f"{name} {text!r} must be numbers separated by commas") from None

    count = None
    if layers.strip() != "auto":
        try:
            count = int(layers)
        except ValueError:
            raise InversionError(f"layers {layers!r} must be a whole number or auto") from None
    cuts = numbers(boundaries, int, "boundaries") if boundaries.strip() else None
    if cuts is not None and count is None:
        count = len(cuts) + 1
    scattering = None
    if mus.strip():
        values = numbers(mus, float, "mus")
        scattering = values[0] if len(values) == 1 else values
    settings = InversionSettings(count, cuts, scattering, n, g, depth, photons, final_photons)
    settings.check()
    return settings
