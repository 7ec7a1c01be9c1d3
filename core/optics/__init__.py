"""Optical properties: per-pixel absorption mu_a and reduced scattering mu_s' of a homogeneous
semi-infinite medium fitted to each pixel's ring profile E_p(r), its diffuse reflectance R_d(f) at
any spatial frequency (what spatial frequency domain imaging measures), region fits and the
calibration of a real rig's scale.

Uses ``inversion`` (its two-layer fit), ``simulate``, ``rings``, ``dataset`` and the shared basics.
"""

from .calibration import Calibration, CalibrationError, calibrate, read_calibration, write_calibration
from .maps import OpticalMaps, optical_maps
from .model import model_profile
from .region import RegionOptics, region_optics
from .transform import diffuse_reflectance, reflectance_maps

__all__ = [
    "Calibration", "CalibrationError", "OpticalMaps", "RegionOptics", "calibrate", "diffuse_reflectance",
    "model_profile", "optical_maps", "read_calibration", "reflectance_maps", "region_optics", "write_calibration",
]
