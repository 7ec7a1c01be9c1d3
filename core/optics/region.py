"""Optical properties of a region: its mean ring profile (the lit points' profiles averaged, rings
cut by the grid's edge weighted as the region's points saw them: :mod:`ringlight.core.inversion.measured`)
fitted as one homogeneous half-space, or, with ``layers=2``, as two layers by the layer inversion
(:mod:`ringlight.core.inversion.layers`); and its diffuse reflectance R_d at spatial frequencies
(:mod:`.transform`), the light beyond the last ring added from the fitted medium.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..inversion.measured import measured_profile
from .pixel_fit import CONVERGED, fit_profiles
from .ring_sigma import ring_sigma
from .maps import DETERMINED_RELATIVE_ERROR, MODEL_FLOOR, OpticsError, profile_radii, sample_optics
from .table import DEFAULT_PHOTONS, table_for
from .transform import diffuse_reflectance, model_tail


@dataclass(frozen=True, eq=False)
class RegionOptics:
    """The optical properties of a region (per channel).

    Attributes
    ----------
    mua, musp, mua_se, musp_se
        (C,) the homogeneous fit and its standard errors, in ``units``.
    determined
        (C,) bool, as :attr:`.maps.OpticalMaps.determined`.
    units, pitch_mm, n, g, channels
        As :class:`.maps.OpticalMaps`.
    frequencies
        (F,) the spatial frequencies asked, in cycles per mm with a pitch, else per grid step.
    reflectance
        (F, C) R_d at them: the rings' transform plus the fitted medium's light beyond them.
    radii, profile, profile_se, model
        (R,) radii (grid steps), (R, C) the region's mean E_r, its standard error and the fitted
        model's E_r (calibration scale included).
    chi2
        (C,) the fit's chi-square over the rings (R - 2 degrees of freedom).
    points
        Lit points averaged.
    layers
        With ``layers=2``: the layer inversion's result
        (:class:`ringlight.core.inversion.layers.Inversion`, per grid step), else None.
    """

    mua: np.ndarray
    musp: np.ndarray
    mua_se: np.ndarray
    musp_se: np.ndarray
    determined: np.ndarray
    units: str
    pitch_mm: float | None
    n: float
    g: float
    channels: tuple[str, ...]
    frequencies: np.ndarray
    reflectance: np.ndarray
    radii: np.ndarray
    profile: np.ndarray
    profile_se: np.ndarray
    model: np.ndarray
    chi2: np.ndarray
    points: int
    layers: object = None

    def undetermined(self) -> list[str]:
        """The names of the channels whose fit is not determined."""
        return [name for name, determined in zip(self.channels, self.determined) if not determined]

    def undetermined_note(self) -> str:
        """``"; not determined in B"`` naming :meth:`undetermined`, or ``""``: the end of a line of
        the region's values."""
        names = self.undetermined()
        return f"; not determined in {', '.join(names)}" if names else ""


def region_optics(dataset: ImpulseDataset, mask: np.ndarray | None = None, *, n: float | None = None,
                  g: float | None = None, calibration=None, layers: int = 1, frequencies=(0.0,),
                  photons: int = DEFAULT_PHOTONS, floor: float = MODEL_FLOOR, progress=None,
                  layer_settings=None) -> RegionOptics:
    """Fit the mean profile of ``mask`` ((H, W) bool; None: the whole grid).

    ``frequencies`` in cycles per mm when the manifest gives ``grid.pitch_mm``, else per grid
    step. ``layers`` 1, or 2 to run the layer inversion on the same profile as well: with
    ``layer_settings`` (an :class:`ringlight.core.inversion.settings.InversionSettings`) or the
    inversion's defaults, two layers of this n and g and the homogeneous fit's scattering.
    ``progress(fraction)`` may raise Cancelled.
    """
    if layers not in (1, 2):
        raise OpticsError(f"a region is fitted with 1 or 2 layers, got {layers}")
    try:
        asked = np.atleast_1d(np.asarray(frequencies, np.float64))
    except (TypeError, ValueError):
        asked = np.array([np.nan])
    if asked.ndim != 1 or not asked.size or not (np.isfinite(asked) & (asked >= 0)).all():
        raise OpticsError(f"frequencies must be one or more finite numbers >= 0, got {frequencies!r}")
    n, g = sample_optics(dataset, n, g)
    height, width = dataset.grid_shape
    mask = np.ones((height, width), bool) if mask is None else np.asarray(mask, bool)
    if mask.shape != (height, width):
        raise OpticsError(f"the region's mask is {mask.shape[0]} x {mask.shape[1]}, the grid {height} x {width}")
    if not (mask & dataset.lit).any():
        raise OpticsError(f"{dataset.path}: the region holds no lit point")
    radii = profile_radii(dataset)
    measured = measured_profile(dataset, mask, radii)
    table = table_for(n, g, radii, photons=photons, ring_weights=measured.ring_weights, progress=progress)
    scale = np.ones(3) if calibration is None else np.asarray(calibration.scale, np.float64)
    mean = measured.mean
    counts = np.full((len(radii), 1, 1), measured.points)
    sigma = ring_sigma(mean[:, None, None], measured.standard_error[:, None, None], counts,
                       np.hypot(floor, measured.floor))
    fitted = fit_profiles(table, mean[:, None, None], sigma, scale)
    u, v = fitted["u"][0, 0], fitted["v"][0, 0]
    pitch = dataset.manifest.pitch_mm
    per = 1.0 / pitch if pitch else 1.0
    musp = (1.0 - g) * np.exp(u) * per
    mua = np.exp(u + v) * per
    musp_se = musp * np.sqrt(fitted["cuu"][0, 0])
    mua_se = mua * np.sqrt(fitted["cuu"][0, 0] + 2.0 * fitted["cuv"][0, 0] + fitted["cvv"][0, 0])
    with np.errstate(invalid="ignore"):
        determined = ((fitted["status"][0, 0] == CONVERGED) & (mua_se < DETERMINED_RELATIVE_ERROR * mua)
                      & (musp_se < DETERMINED_RELATIVE_ERROR * musp))
    model = np.stack([scale[c] * table.profile(musp[c] / per, mua[c] / per) if np.isfinite(mua[c])
                      else np.full(len(radii), np.nan) for c in range(3)], axis=1)
    per_step = asked * pitch if pitch else asked
    reflectance = diffuse_reflectance(radii, mean, per_step)
    beyond = radii[-1] + 0.5
    for c in range(3):
        if np.isfinite(mua[c]):
            mus = musp[c] / per / (1.0 - g)
            reflectance[:, c] += scale[c] * model_tail(table.run, mus, mua[c] / per, per_step, beyond)
    inversion = None
    if layers == 2:
        from ..inversion.layers import invert
        from ..inversion.settings import InversionSettings

        from dataclasses import replace

        mus = float(np.nanmean(musp / per)) / (1.0 - g) if np.isfinite(musp).any() else None
        settings = replace(layer_settings or InversionSettings(), layers=2, n=n, g=g)
        if settings.mus is None and settings.boundaries is None:
            settings = replace(settings, mus=mus)
        inversion = invert(measured, settings, dataset.colorspace)
    return RegionOptics(mua, musp, mua_se, musp_se, determined, "per_mm" if pitch else "per_grid_step", pitch, n, g,
                        ("R", "G", "B"), asked, reflectance, radii, mean, measured.standard_error, model,
                        fitted["chi2"][0, 0], measured.points, inversion)
