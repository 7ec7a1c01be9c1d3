"""The scale of a real rig, calibrated on a reference material as SFDI calibrates on a phantom.

A simulated dataset is absolute: its frames are the reflectance factor per unit beam power
(docs/format/scene.md). A real capture's frames are in the camera's units, ``s`` times that, with
``s`` per channel unknown (projector power, exposure, camera gain, the lens's collection). A scan
of a reference of known absorption and reduced scattering (a phantom, or any material measured
elsewhere) gives it: the region-mean profile of the reference over the model's profile of its
known properties, by weighted least squares over the rings::

    s = sum_r E_r M_r / sigma_r^2 / sum_r M_r^2 / sigma_r^2

Later scans on the same rig (same projector, camera, exposure units and grid pitch) divide by it:
:func:`ringlight.core.optics.maps.optical_maps` multiplies the model by it. The calibration file
(``docs/format/calibration.md``, schema ``resources/schemas/calibration.schema.json``) is JSON::

    {"format": "ringlight-calibration", "version": 1, "channels": ["R", "G", "B"],
     "scale": [sR, sG, sB], "scale_se": [...],
     "reference": {"mua": [...], "musp": [...], "units": "per_mm", "n": 1.4, "g": 0.0,
                   "description": "..."},
     "provenance": {"dataset": "...", "created": "2026-11-26T21:00:00Z", "software": "ringlight 0.1.0",
                    "radii": [0, 1, ...], "pitch_mm": 0.1}}
"""

from __future__ import annotations

import datetime
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_file
from ..dataset.impulse_dataset import ImpulseDataset
from ..errors import RinglightError
from ..inversion.measured import measured_profile
from ..validation import Validator, read_json
from .maps import CHANNELS, MODEL_FLOOR, profile_radii, sample_optics
from .ring_sigma import ring_sigma
from .table import DEFAULT_PHOTONS, table_for

FORMAT = "ringlight-calibration"
VERSION = 1
UNITS = ("per_mm", "per_grid_step")
SCALE_RANGE = (1e-30, 1e30)
"""Bounds of a scale and of its standard error (camera units per unit of the model's E). E is a
reflectance factor (below 1) and frames hold float32 readings (at most 3.4e38), so a real rig's
scale lies far inside; within them the fits' float64 sums of (scale E / sigma)^2 and their inverses
cannot overflow, where a scale of 1e308 makes them Inf and every map NaN."""


class CalibrationError(RinglightError):
    """A calibration that cannot be made, read or used."""


@dataclass(frozen=True)
class Calibration:
    """A rig's scale per channel and what it was measured on.

    Attributes
    ----------
    scale, scale_se
        (C,) camera units per unit of the model's E (reflectance factor per unit beam power),
        within :data:`SCALE_RANGE`, and its standard error.
    reference_mua, reference_musp
        (C,) the reference's known properties, in ``units``.
    units
        ``"per_mm"`` or ``"per_grid_step"``.
    n, g
        The reference's refractive index and anisotropy.
    description
        What the reference is (free text).
    provenance
        Where the calibration came from: ``dataset``, ``created`` (UTC, ISO 8601), ``software``,
        ``radii``, ``pitch_mm``.
    channels
        Channel names: always :data:`~.maps.CHANNELS` (R, G, B), the order of the per-channel values.
    """

    scale: tuple[float, ...]
    scale_se: tuple[float, ...]
    reference_mua: tuple[float, ...]
    reference_musp: tuple[float, ...]
    units: str
    n: float
    g: float
    description: str = ""
    provenance: dict = field(default_factory=dict)
    channels: tuple[str, ...] = ("R", "G", "B")


def calibrate(dataset: ImpulseDataset, reference_mua, reference_musp, *, n: float | None = None,
              g: float | None = None, mask: np.ndarray | None = None, description: str = "",
              photons: int = DEFAULT_PHOTONS) -> Calibration:
    """The scale of the rig that captured ``dataset``, a scan of a reference of known properties.

    Parameters
    ----------
    dataset
        The reference's scan.
    reference_mua, reference_musp
        Its absorption and reduced scattering, one number or one per channel: per mm when the
        manifest gives ``grid.pitch_mm``, else per grid step.
    n, g
        Its refractive index and anisotropy (None: the manifest's ``sample``).
    mask
        (H, W) bool the region of the reference to use (None: the whole grid).
    description
        What the reference is, kept in the calibration.
    """
    n, g = sample_optics(dataset, n, g)
    try:
        mua = np.broadcast_to(np.asarray(reference_mua, np.float64), (3,)).copy()
        musp = np.broadcast_to(np.asarray(reference_musp, np.float64), (3,)).copy()
    except (TypeError, ValueError):  # numpy's own words ("could not be broadcast ... remapped shapes")
        raise CalibrationError(f"the reference's mua and musp must each be one number or one per channel (3), "
                               f"got {reference_mua!r} and {reference_musp!r}") from None
    if not (np.isfinite(mua).all() and np.isfinite(musp).all() and (mua > 0).all() and (musp > 0).all()):
        raise CalibrationError(f"the reference's mua and musp must be positive numbers, got {mua.tolist()} and "
                               f"{musp.tolist()}")
    pitch = dataset.manifest.pitch_mm
    per_step = pitch if pitch else 1.0
    radii = profile_radii(dataset)
    height, width = dataset.grid_shape
    region = np.ones((height, width), bool) if mask is None else np.asarray(mask, bool)
    measured = measured_profile(dataset, region, radii)
    table = table_for(n, g, radii, photons=photons, ring_weights=measured.ring_weights)
    sigma = ring_sigma(measured.mean[:, None, None], measured.standard_error[:, None, None],
                       np.full((len(radii), 1, 1), measured.points), np.hypot(MODEL_FLOOR, measured.floor))[:, 0, 0]
    scale, scale_se = np.empty(3), np.empty(3)
    for c in range(3):
        model = table.profile(musp[c] * per_step, mua[c] * per_step)
        if not np.isfinite(model).all():
            low, high = table.reduced_scattering_range
            raise CalibrationError(f"the reference's properties (mua {mua[c]:g}, musp {musp[c]:g}) lie outside the "
                                   f"model's table (musp {low / per_step:.3g} to {high / per_step:.3g})")
        used = np.isfinite(measured.mean[:, c]) & np.isfinite(sigma[:, c]) & (sigma[:, c] > 0)
        weight = 1.0 / sigma[used, c].astype(np.float64) ** 2  # float32 squares of a bright rig's sigma overflow
        information = float((model[used] ** 2 * weight).sum())
        scale[c] = float((measured.mean[used, c] * model[used] * weight).sum()) / information
        scale_se[c] = 1.0 / math.sqrt(information)
    low, high = SCALE_RANGE
    if not ((scale >= low) & (scale <= high)).all():  # NaN too: a file that read_calibration refuses is never made
        raise CalibrationError(f"{dataset.path}: the reference's scan gives no scale within [{low:g}, {high:g}] "
                               f"({scale.tolist()})")
    provenance = {"dataset": str(dataset.path), "created": _now(), "software": f"ringlight {_version()}",
                  "radii": radii.tolist(), "pitch_mm": pitch}
    return Calibration(tuple(scale.tolist()), tuple(scale_se.tolist()), tuple(mua.tolist()), tuple(musp.tolist()),
                       "per_mm" if pitch else "per_grid_step", n, g, description, provenance)


def calibration_document(calibration: Calibration) -> dict:
    """The calibration as the file holds it."""
    return {"format": FORMAT, "version": VERSION, "channels": list(calibration.channels),
            "scale": list(calibration.scale), "scale_se": list(calibration.scale_se),
            "reference": {"mua": list(calibration.reference_mua), "musp": list(calibration.reference_musp),
                          "units": calibration.units, "n": calibration.n, "g": calibration.g,
                          "description": calibration.description},
            "provenance": dict(calibration.provenance)}


def write_calibration(path, calibration: Calibration, *, overwrite: bool = False) -> None:
    """Write ``calibration`` to ``path`` as JSON, atomically; an existing file is replaced only
    with ``overwrite`` and only when it is a calibration file (never a file ringlight did not write)."""
    path = Path(path)
    if overwrite and path.exists():
        read_calibration(path)  # refuses (CalibrationError) to replace what is not a calibration
    text = json.dumps(calibration_document(calibration), indent=1) + "\n"
    with atomic_file(path, overwrite=overwrite) as temporary:
        temporary.write_text(text, encoding="utf-8")


def read_calibration(path) -> Calibration:
    """The calibration in ``path``; CalibrationError with one line naming the file and the
    problem when it is not one."""
    document = read_json(path, CalibrationError, "calibration file")
    return parse_calibration(document, str(path))


def parse_calibration(document: object, where: str = "calibration") -> Calibration:
    """Validate a decoded calibration document (:func:`read_calibration`)."""
    check = Validator(where, CalibrationError)
    doc = check.mapping(document, "calibration", {"format", "version", "channels", "scale", "scale_se", "reference",
                                                  "provenance"}, {"format", "version", "scale", "reference"})
    if doc["format"] != FORMAT:
        raise check.fail("format", f"the string {FORMAT!r}", doc["format"])
    if doc["version"] != VERSION or isinstance(doc["version"], bool):
        raise check.fail("version", f"{VERSION} (this ringlight reads version {VERSION})", doc["version"])
    channels = doc.get("channels", list(CHANNELS))
    if channels != list(CHANNELS):  # the maps' channels; a monochrome (Y) dataset is read as R = G = B
        raise check.fail("channels", f"{json.dumps(list(CHANNELS))} (scale and reference are in that order)",
                         channels)
    scale, scale_se = _scales(check, doc)
    reference = check.mapping(doc["reference"], "reference", {"mua", "musp", "units", "n", "g", "description"},
                              {"mua", "musp", "units", "n"})
    mua = check.numbers(reference["mua"], "reference.mua", 3)
    musp = check.numbers(reference["musp"], "reference.musp", 3)
    if any(v <= 0 for v in mua + musp):
        raise check.fail("reference.mua", "positive coefficients (mua and musp)", reference["mua"])
    units = check.string(reference["units"], "reference.units")
    if units not in UNITS:
        raise check.fail("reference.units", f"one of {', '.join(UNITS)}", units)
    n = check.number(reference["n"], "reference.n")
    if not 1.0 <= n <= 3.0:
        raise check.fail("reference.n", "a refractive index in [1, 3]", reference["n"])
    g = check.number(reference.get("g", 0.0), "reference.g")
    if not -1.0 < g < 1.0:
        raise check.fail("reference.g", "an anisotropy in (-1, 1)", reference["g"])
    description = check.string(reference.get("description", ""), "reference.description")
    provenance = check.mapping(doc.get("provenance", {}), "provenance", None, set())
    return Calibration(scale, scale_se, mua, musp, units, n, g, description, dict(provenance), tuple(channels))


def _scales(check: Validator, doc: dict) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The document's (3,) ``scale`` within :data:`SCALE_RANGE` and (3,) ``scale_se`` within [0, its
    top] (NaN when the file has none); CalibrationError naming the key otherwise."""
    low, high = SCALE_RANGE
    scale = check.numbers(doc["scale"], "scale", 3)
    if not all(low <= s <= high for s in scale):
        raise check.fail("scale", f"3 positive numbers within [{low:g}, {high:g}]", doc["scale"])
    if "scale_se" not in doc:
        return scale, (math.nan,) * 3
    scale_se = check.numbers(doc["scale_se"], "scale_se", 3)
    if not all(0.0 <= s <= high for s in scale_se):
        raise check.fail("scale_se", f"3 standard errors within [0, {high:g}]", doc["scale_se"])
    return scale, scale_se


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ringlight")
    except PackageNotFoundError:
        return "unknown"
