"""What the explorer computes off the GUI thread: opening a dataset for viewing, and its stacks.

Both are plain functions of frozen inputs with a ``progress`` callback, so they run in a worker
(:mod:`ringlight.widgets.jobs`) and in tests alike. A dataset is opened together with its first
stacks, so the window swaps from the old dataset to the new one in one step and never shows a
half-loaded state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ringlight.core import ImpulseDataset, RinglightError, load_manifest, open_dataset
from ringlight.core.colour.first_view import FirstView, first_view
from ringlight.core.compile_ahead import start_compiling
from ringlight.core.dataset.ground_truth import (
    PathLengthImages,
    read_path_length_images,
    stack_correlations,
)
from ringlight.core.device import Device
from ringlight.core.phases import phase
from ringlight.core.rings.coverage import coverage_warning
from ringlight.core.rings.profiles import ProfileRings, profile_rings
from ringlight.core.rings.stack_cache import cached_coverage, cached_stacks
from ringlight.core.rings.stack_request import (
    StackPair,
    StackRequest,
    default_request,
)
from ringlight.core.simulate.samples import DEMO_SAMPLE, sample_dataset

Progress = Callable[[float], None]

OPEN_RADIUS = 24.0
"""Radius (grid steps) up to which responses are kept for datasets without ``max_radius``, unless
the requested stack needs more."""


Preview = Callable[[np.ndarray, int, str], None]


@dataclass(frozen=True, eq=False)
class ViewStacks:
    """A request's stacks plus what the explorer derives from them once.

    Attributes
    ----------
    correlations
        (n,) NCC of each T_r with its nearest ground-truth bin, or None without ground truth.
    poor_coverage
        (n,) bool: radii whose rings the dataset's lit points cover poorly
        (:func:`ringlight.core.rings.coverage.coverage_warning`); ``coverage_note`` its one line,
        or None when every ring is well covered.
    """

    pair: StackPair
    rings: ProfileRings
    correlations: np.ndarray | None
    poor_coverage: np.ndarray
    coverage_note: str | None


@dataclass(frozen=True, eq=False)
class LoadedDataset:
    """An opened dataset with everything the explorer shows before the first click.

    Attributes
    ----------
    steady_state
        (H, W, 3) float32 appearance under full illumination.
    truth
        Ground-truth path-length images, or None.
    """

    dataset: ImpulseDataset
    steady_state: np.ndarray
    truth: PathLengthImages | None
    stacks: ViewStacks
    notice: str | None = None
    """A line for the user about the open (the stack asked for could not be made), or None."""
    first_view: FirstView | None = None
    """Where the stacks show the dataset's structure (:mod:`ringlight.core.colour.first_view`),
    when it opened without a stack last shown for it (a first open), else None."""


def scaled(progress: Progress, low: float, high: float) -> Progress:
    """A progress callback reporting ``[0, 1]`` as ``[low, high]`` of ``progress``."""
    return lambda fraction: progress(low + (high - low) * fraction)


def open_radius(manifest_max_radius: float | None, height: int, width: int, request: StackRequest | None) -> float | None:
    """Radius to open a dataset at: None (the manifest's) when it sets ``max_radius``."""
    if manifest_max_radius is not None:
        return None
    wanted = OPEN_RADIUS
    if request is not None:
        try:
            wanted = max(wanted, request.reach())
        except RinglightError:
            pass
    return min(wanted, math.hypot(height - 1, width - 1))


def load_for_viewing(path: str | Path | None, request: StackRequest | None, progress: Progress,
                     sample: str | None = None, preview: Preview | None = None,
                     device: Device | None = None) -> LoadedDataset:
    """Open ``path`` with its stacks; with ``sample``, that bundled sample, and with neither the
    demo dataset (each written into the user cache first, the first time).

    ``request`` is used when the dataset can serve it, else :func:`default_request`.
    ``preview(steady, rows, colorspace)`` gets the steady state as it becomes known: (H, W, 3)
    float32 linear RGB in the dataset's ``colorspace``, its first ``rows`` rows filled and the
    rest NaN, after each band of an out-of-core build, and
    whole once the dataset is open, before the stacks are computed (the longest part of opening
    a big dataset from its store). The stacks' rings are summed on ``device`` (the CPU when None).
    """
    # A fresh install's first open: its kernels compiled side by side, in processes, while the sample
    # is written and the manifest read (a manifest's error is not kept waiting for them).
    compilation = start_compiling()
    if path is None:
        path = sample_dataset(sample or DEMO_SAMPLE, progress=scaled(progress, 0.0, 0.3))
        progress = scaled(progress, 0.3, 1.0)
    manifest = load_manifest(path)
    if compilation is not None:
        phase("compiling ringlight's kernels (first start after an install or update)")
        compilation.wait(scaled(progress, 0.0, 0.5))
        progress = scaled(progress, 0.5, 1.0)
    radius = open_radius(manifest.max_radius, manifest.height, manifest.width, request)
    dataset = open_dataset(manifest, radius=radius, progress=scaled(progress, 0.0, 0.5),
                           preview=None if preview is None else _band_preview(manifest, preview))
    steady_state = dataset.steady_state()
    if preview is not None:
        preview(steady_state, manifest.height, manifest.colorspace)
    progress(0.55)
    if manifest.ground_truth is not None:
        phase("reading the ground truth")
    truth = read_path_length_images(manifest, progress=scaled(progress, 0.55, 0.65))
    refusal = None if request is None else _refusal(dataset, request)
    notice = None if refusal is None else (f"The stack last shown for {dataset.path.name} cannot be made now "
                                           f"({refusal}); showing the default")
    first_open = request is None
    if request is None or refusal is not None:
        request = default_request(dataset.max_radius)
    stacks = compute_view_stacks(dataset, truth, request, scaled(progress, 0.65, 1.0), device)
    view = None
    if first_open:
        transient = stacks.pair.transient
        view = first_view(transient.images, transient.counts, transient.outer_counts, dataset.colorspace)
    return LoadedDataset(dataset, steady_state, truth, stacks, notice, view)


def _band_preview(manifest, preview: Preview):
    """The open's band callback: each band's rows into one image, passed on to ``preview``."""
    canvas = np.full((manifest.height, manifest.width, 3), np.nan, np.float32)

    def band(row0: int, row1: int, steady: np.ndarray) -> None:
        canvas[row0:row1] = steady
        preview(canvas.copy(), row1, manifest.colorspace)
    return band


def compute_view_stacks(dataset: ImpulseDataset, truth: PathLengthImages | None, request: StackRequest,
                        progress: Progress, device: Device | None = None) -> ViewStacks:
    """Stacks of ``request`` (from the cache when a previous open saved them, else with the rings
    summed on ``device``: :func:`ringlight.core.rings.stack_cache.cached_stacks`) with profile rings
    and ground-truth correlations."""
    pair = cached_stacks(dataset, request, scaled(progress, 0.0, 0.9), device)
    phase("placing the profiles' rings")
    rings = profile_rings(dataset, pair.radii, request.dr, request.thickness, request.antialias)
    correlations = None
    if truth is not None:
        phase("comparing with the ground truth")
        correlations = stack_correlations(pair.radii, request.dr, pair.transient.images, truth)
    coverage = cached_coverage(dataset, request)
    progress(1.0)
    return ViewStacks(pair, rings, correlations, coverage.poor(), coverage_warning(coverage))


def _refusal(dataset: ImpulseDataset, request: StackRequest) -> str | None:
    """Why ``dataset`` cannot serve ``request``, or None."""
    try:
        request.check(dataset)
    except RinglightError as error:
        return str(error)
    return None
