"""The fitted model's ring profile, for one pixel and channel: what the explorer draws over the
measured E(r)."""

from __future__ import annotations

import numpy as np

from .table import DEFAULT_PHOTONS, table_for


def model_profile(mua: float, musp: float, radii, *, n: float, g: float = 0.0, pitch_mm: float | None = None,
                  scale: float = 1.0, thickness: float = 1.0, photons: int = DEFAULT_PHOTONS) -> np.ndarray:
    """E(r) of a homogeneous half-space of absorption ``mua`` and reduced scattering ``musp``.

    Parameters
    ----------
    mua, musp
        Per mm when ``pitch_mm`` is given (the units of :class:`.maps.OpticalMaps` with
        ``units == "per_mm"``), else per grid step.
    radii
        (R,) ring radii, grid steps.
    n, g
        Refractive index and anisotropy.
    scale
        The rig's scale for the channel (:attr:`ringlight.core.optics.calibration.Calibration.scale`; 1 for a
        simulated dataset).
    thickness, photons
        The rings' thickness, the table's white run (:func:`.table.table_for`).

    Returns
    -------
    np.ndarray
        (R,) float64 in the units and normalisation of the ring light stack's E_r
        (:class:`ringlight.core.rings.profiles.PixelProfile` ``ring``): the mean over whole rings;
        NaN outside the table's range of scattering and absorption.
    """
    per_step = float(pitch_mm) if pitch_mm else 1.0
    table = table_for(n, g, np.asarray(radii, np.float64), thickness, photons=photons)
    return scale * table.profile(musp * per_step, mua * per_step)
