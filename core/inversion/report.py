"""An inversion of a dataset's region end to end, and its result as JSON (CLI and window share it)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..colour.chroma import chromaticity
from ..colour.layer_report import finite_or_none, truth_layers
from ..dataset.impulse_dataset import ImpulseDataset
from .layer_colour import region_contains
from .limit import TOLERANCE_XY
from ..phases import phase
from .layers import Inversion, Progress, invert
from .search import REACH
from .settings import InversionSettings
from .measured import measured_profile


@dataclass(frozen=True, eq=False)
class DatasetInversion:
    """An inversion with the region it describes and the dataset's ground truth, when it has one.

    ``truth_xy`` is (K, 2) for the truth's K layers (None without); ``errors`` and ``inside`` hold
    each fitted layer's xy distance to the truth layer of the same index and whether the truth lies
    in its two-sigma region (None unless the layer counts agree)."""

    inversion: Inversion
    region_description: str
    truth_names: tuple[str, ...]
    truth_xy: np.ndarray | None
    errors: list[float] | None
    inside: list[bool] | None


def profile_radii(dataset: ImpulseDataset) -> np.ndarray:
    """Radii 0, 1, ... whose rings (thickness 1) lie within the dataset's max_radius and within the
    white databases' :data:`~.search.REACH` (rings to r = 13 at most).

    A capture at the paper's scale (max_radius 24) has rings beyond what a database keeps. They add
    little: fitted without error at 0.1 % noise per ring (``tools/inversion_limit.py``, 80 000 white
    photons), layers3's two-sigma regions were 0.087 / 0.147 / 0.288 wide in xy from rings 0..11
    and 0.083 / 0.134 / 0.255 from rings 0..20, at a database three times as large (records within
    21 pixels) that every fit of a search would read."""
    return np.arange(0.0, min(math.floor(dataset.max_radius - 0.5), REACH) + 1.0)


def invert_region(dataset: ImpulseDataset, region: np.ndarray, region_description: str,
                  settings: InversionSettings, progress: Progress | None = None,
                  fit: Callable[..., Inversion] = invert) -> DatasetInversion:
    """Measure ``region``'s profile and invert it (see :func:`ringlight.core.inversion.layers.invert`),
    with the index and anisotropy the dataset states where ``settings`` give none. ``fit``, called
    as :func:`~ringlight.core.inversion.layers.invert` is (profile, settings, colourspace,
    progress), runs the fit: the window's runs it in a process of its own."""
    settings.check()
    phase("measuring the region's profile")
    measured = measured_profile(dataset, region, profile_radii(dataset))
    sample = dataset.manifest.sample
    inversion = fit(measured, settings.for_dataset(sample), dataset.colorspace, progress)
    stated = [f"{name} {value:g}" for name, value, given in (("n", sample.n, settings.n), ("g", sample.g, settings.g))
              if value is not None and given is None]
    if stated:
        inversion = replace(inversion, notes=f"{inversion.notes}; {' and '.join(stated)} as the dataset states "
                                             f"(its manifest's sample key)")
    names, truth_rgb = truth_layers(dataset)
    truth_xy = chromaticity(truth_rgb, dataset.colorspace) if truth_rgb is not None else None
    errors = inside = None
    if truth_xy is not None and len(truth_xy) == len(inversion.layers):
        errors = [float(np.hypot(*(layer.xy - xy))) for layer, xy in zip(inversion.layers, truth_xy)]
        inside = [region_contains(layer.region, xy) for layer, xy in zip(inversion.layers, truth_xy)]
    return DatasetInversion(inversion, region_description, names, truth_xy, errors, inside)


def inversion_document(result: DatasetInversion, dataset_path: str) -> dict:
    """The JSON document of an inversion (NaN written as null)."""
    inversion = result.inversion
    layers = []
    for index, layer in enumerate(inversion.layers):
        entry = {
            "depth": [layer.top, layer.bottom], "mus": layer.mus, "mua": finite_or_none(layer.mua),
            "mua_two_sigma": [finite_or_none(row) for row in layer.mua_interval],
            "determined": layer.determined, "not_determined_because": layer.reason or None,
            "rgb": finite_or_none(layer.rgb), "xy": finite_or_none(layer.xy), "srgb8": "#%02x%02x%02x" % layer.swatch,
            "xy_two_sigma_region": [finite_or_none(point) for point in layer.region],
            "xy_two_sigma_width": _number(layer.region_width),
            "xy_width_the_data_allow": _number(layer.allowed_width),
            "within_tolerance": layer.allowed_width <= TOLERANCE_XY, "beyond_tolerance_because": layer.limit or None,
        }
        if result.errors is not None:
            entry.update(truth=result.truth_names[index], truth_xy=finite_or_none(result.truth_xy[index]),
                         xy_error=result.errors[index], truth_in_region=result.inside[index])
        layers.append(entry)
    return {
        "format": "ringlight-layers", "version": 1, "dataset": dataset_path, "method": "inverse",
        "region": result.region_description, "model": inversion.notes,
        "fit": {"chi2": _number(inversion.chi2), "dof": inversion.dof, "chi2_per_dof": _number(inversion.chi2_per_dof),
                "rings_used": {"R": int(inversion.used[0]), "G": int(inversion.used[1]), "B": int(inversion.used[2])},
                "warning": inversion.warning, "seconds": round(inversion.seconds, 2)},
        "uncertainty": ("two-sigma (95.4 %) region of the three channels together: the per-channel profile-likelihood "
                        "region, joined with the joint fit's ellipse where its chi-square is close to quadratic; "
                        "see ringlight.core.inversion.layer_colour. xy_width_the_data_allow: the width of the "
                        "same two-sigma region with the fitted model taken as exact, at the data's noise alone "
                        "(replicates' spread, or ring spread and floor): no white-run noise, no rival models "
                        f"(ringlight.core.inversion.limit); within_tolerance: it is at most {TOLERANCE_XY:g}"),
        "profile": {"radii": finite_or_none(inversion.measured.radii),
                    "measured": [finite_or_none(row) for row in inversion.measured.mean],
                    "standard_error": [finite_or_none(row) for row in inversion.measured.standard_error],
                    "model": [finite_or_none(row) for row in inversion.model],
                    "sigma": [finite_or_none(row) for row in inversion.sigma]},
        "layers": layers,
    }


def inversion_json(result: DatasetInversion, dataset_path: str) -> str:
    return json.dumps(inversion_document(result, dataset_path), indent=1, allow_nan=False) + "\n"


def _number(value: float):
    return float(value) if math.isfinite(value) else None
