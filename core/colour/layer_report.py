"""Layer colour recovery end to end, and its results as JSON and CSV (CLI and window share it).

A recovered layer is *trusted* when the transient it comes from stands out of its noise: the
region-mean luminance of T_r is at least MIN_SNR (3) standard errors above zero, the standard
error from the spread of each pixel's ring members (:mod:`ringlight.core.rings.noise`), which is
an upper bound of the noise where the surface itself varies.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass, replace

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..errors import StackError
from ..rings.noise import StackNoise, region_snr, stack_noise
from ..rings.stack_request import StackRequest, largest_stop
from ..rings.stacks import Stack, transient_stack
from .chroma import MIN_SNR, LayerResult, Trajectory, propose_radii, recover_layers, trajectory

MOST_ANALYSIS_RADII = 256
"""Transient images a layer analysis's stack may hold (the explorer's default stack holds 64)."""
TRUST_RULE = (f"trusted: the region-mean luminance of T_r is at least {MIN_SNR:g} standard errors above 0; "
              "standard errors from the spread of each pixel's ring members (SE of T_r from both rings), "
              "an upper bound of the noise where the surface itself varies")
"""The trusted flag's rule, as the reports and the Layers tab state it."""


@dataclass(frozen=True, eq=False)
class LayerAnalysis:
    """A trajectory over a region and the layers recovered from it."""

    region_description: str
    path: Trajectory
    result: LayerResult
    truth_names: tuple[str, ...] = ()


def with_ring_noise(path: Trajectory, stack: Stack, noise: StackNoise, region: np.ndarray) -> Trajectory:
    """``path`` (the trajectory of transient ``stack`` over the (H, W) bool ``region``) with its
    ``snr`` replaced by the region-mean T_r luminance SNR from the ring-member spread
    (:func:`ringlight.core.rings.noise.region_snr`): the number the trusted flag tests
    (``Trajectory.trusted``: luminance > 0 and snr >= MIN_SNR), in recovery and auto picks."""
    return replace(path, snr=region_snr(stack.images, noise, region))


def layer_snr(analysis: LayerAnalysis) -> list[float]:
    """The SNR behind each recovered layer's trusted flag (its transient's, see :data:`TRUST_RULE`)."""
    path = analysis.path
    return [float(path.snr[int(np.argmin(np.abs(path.radii - layer.radius)))]) for layer in analysis.result.layers]


def analysis_stack_request(dataset: ImpulseDataset, step: float = 1.0, dr: float = 1.0,
                           thickness: float = 1.0) -> StackRequest:
    """Radii 0, step, ... as far as the dataset's max_radius allows, at most
    :data:`MOST_ANALYSIS_RADII` of them (StackError beyond: a step of 1e-6 asked for millions of
    images)."""
    request = StackRequest(0.0, 0.0, step, dr=dr, thickness=thickness)
    request = request.with_changes(stop=largest_stop(dataset.max_radius, request))
    count = len(request.radii())
    if count > MOST_ANALYSIS_RADII:
        raise StackError(f"a radius step of {step:g} gives {count} transient images up to r = {request.stop:g}; "
                         f"at most {MOST_ANALYSIS_RADII}: use a step of at least "
                         f"{request.stop / (MOST_ANALYSIS_RADII - 1):.3g}")
    return request


def truth_layers(dataset: ImpulseDataset) -> tuple[tuple[str, ...], np.ndarray | None]:
    """Names and (K, 3) linear RGB of the dataset's ground-truth layers (None without)."""
    truth = dataset.manifest.ground_truth
    if truth is None or not truth.layers:
        return (), None
    return tuple(layer.name for layer in truth.layers), np.array([layer.rgb for layer in truth.layers], np.float64)


def analyse_layers(dataset: ImpulseDataset, region: np.ndarray, region_description: str, *,
                   radii=None, auto: int | None = None, method: str = "paper", request: StackRequest | None = None,
                   progress=None) -> LayerAnalysis:
    """Transient stack over ``request`` (default :func:`analysis_stack_request`) and its noise,
    trajectory over ``region`` with the noise's SNR, and layers from ``radii`` or ``auto``
    proposed radii."""
    request = request or analysis_stack_request(dataset)
    request.check(dataset)
    half = (lambda fraction: progress(fraction / 2)) if progress else None
    stack = transient_stack(dataset, request.radii(), request.dr, request.thickness, request.antialias, half)
    noise = stack_noise(dataset, request.radii(), request.dr, request.thickness, request.antialias,
                        (lambda fraction: progress(0.5 + fraction / 2)) if progress else None)
    path = with_ring_noise(trajectory(stack, region), stack, noise, region)
    if radii is None:
        radii = propose_radii(path, 3 if auto is None else auto)
    names, truth_rgb = truth_layers(dataset)
    result = recover_layers(path, radii, method, truth_rgb)
    return LayerAnalysis(region_description, path, result, names)


def analysis_document(analysis: LayerAnalysis, dataset_path: str) -> dict:
    """A JSON-ready description: picked radii, per-layer xy, RGB and swatch, truth and errors."""
    result, path = analysis.result, analysis.path
    document = {
        "format": "ringlight-layers", "version": 1,
        "dataset": dataset_path, "region": analysis.region_description, "method": result.method,
        "colorspace": path.colorspace, "radii": list(result.radii), "trust": TRUST_RULE,
        "layers": [
            {"radius": layer.radius, "xy": finite_or_none(layer.xy), "rgb": finite_or_none(layer.rgb),
             "srgb8": list(layer.srgb8), "snr": finite_or_none([snr])[0], "trusted": layer.trusted, "note": layer.note}
            for layer, snr in zip(result.layers, layer_snr(analysis))
        ],
        "warnings": list(result.warnings),
        "trajectory": {
            "radii": path.radii.tolist(), "xy": [finite_or_none(xy) for xy in path.xy],
            "luminance": finite_or_none(path.luminance), "snr": finite_or_none(path.snr),
        },
    }
    if result.truth_xy is not None:
        document["truth"] = [{"name": name, "xy": list(xy)} for name, xy in zip(analysis.truth_names, result.truth_xy)]
        document["xy_errors"] = finite_or_none(result.errors)
    return document


def analysis_json(analysis: LayerAnalysis, dataset_path: str) -> str:
    return json.dumps(analysis_document(analysis, dataset_path), indent=1, allow_nan=False) + "\n"


def analysis_csv(analysis: LayerAnalysis) -> str:
    """One row per recovered layer; truth and error columns empty when unknown."""
    buffer = io.StringIO()
    buffer.write(f"# ringlight layers: method {analysis.result.method}, region {analysis.region_description}\n")
    buffer.write(f"# {TRUST_RULE}\n")
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["layer", "radius", "x", "y", "R", "G", "B", "sRGB8", "snr", "trusted", "truth_x", "truth_y",
                     "xy_error"])
    result = analysis.result
    for index, (layer, snr) in enumerate(zip(result.layers, layer_snr(analysis))):
        truth = result.truth_xy[index] if result.truth_xy and index < len(result.truth_xy) else ("", "")
        error = result.errors[index] if result.errors and index < len(result.errors) else ""
        writer.writerow([index + 1, layer.radius, *layer.xy, *layer.rgb, "#%02x%02x%02x" % layer.srgb8, snr,
                         layer.trusted, *truth, error])
    return buffer.getvalue()


def finite_or_none(values):
    """JSON has no NaN: None in its place."""
    return [None if not np.isfinite(value) else float(value) for value in values]
