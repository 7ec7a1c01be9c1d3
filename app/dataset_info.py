"""What a dataset is, in the lines ``ringlight info`` prints and the explorer's Help > Dataset
information shows: grid, frames, channels, lit points, radius, the responses' size, where its store
is and how much memory an open takes, ground truth and notes."""

from __future__ import annotations

import numpy as np
from ringlight.core import DatasetError, effective_max_radius
from ringlight.core.colourspaces import CUSTOM_PREFIX
from ringlight.core.dataset.frames import dataset_channels
from ringlight.core.dataset.manifest import Manifest
from ringlight.core.dataset.open_plan import plan_open
from ringlight.core.simulate.transport import simulated_before_camera_measure, simulated_measure


def _describe_channels(manifest, allow_outside: bool) -> str:
    """``"R, G, B"``, ``"Y (monochrome: grey, layer colours need an RGB camera)"``, with the part."""
    try:
        channels = dataset_channels(manifest, allow_outside)
    except DatasetError:  # the first frame's problem is listed with the file problems
        channels = manifest.channels or ("R", "G", "B")
    text = ", ".join(channels)
    if len(channels) == 1:
        text += " (monochrome: grey, layer colours need an RGB camera)"
    return text + (f" of part {manifest.part!r}" if manifest.part is not None else "")


def describe_dataset(manifest: Manifest, allow_outside: bool = False, radius: float | None = None) -> list[str]:
    """The description's lines ("key          value"; reads no frame's pixels); ``radius``: the
    max radius it is (or would be) opened at (None: as an open without one)."""
    counts = manifest.lit_counts()
    lit = int(np.count_nonzero(counts))
    missing = counts.size - lit
    pitch = f", pitch {manifest.pitch_mm:g} mm" if manifest.pitch_mm else ""
    points_per_frame = manifest.frames.counts
    exposures = np.unique(manifest.frames.exposures).tolist()
    lines = [
        f"dataset      {manifest.folder}",
        f"grid         {manifest.height} x {manifest.width}{pitch}",
        f"colorspace   {manifest.colorspace.removeprefix(CUSTOM_PREFIX)}",
        f"channels     {_describe_channels(manifest, allow_outside)}",
        f"frames       {len(manifest.frames)} in {manifest.frame_space} frame space"
        f" ({points_per_frame.min()}-{points_per_frame.max()} lit points per frame;"
        f" exposures {', '.join(f'{e:g}' for e in exposures[:6])}{' ...' if len(exposures) > 6 else ''})",
        f"lit points   {lit} (lit in several frames: {int(np.count_nonzero(counts > 1))})",
        f"missing      {missing} point(s) lit in no frame",
        f"dark frame   {manifest.dark or 'none'}",
    ]
    replicates = manifest.replicates
    if len(replicates) > 1:
        lines.append(f"replicates   {len(replicates)}: standard errors from their spread, shared noise included")
    else:
        lines.append("replicates   none: standard errors from each ring's spread, blind to shared noise")
    sample = manifest.sample
    if sample.n is not None or sample.g is not None:
        stated = ", ".join(f"{name} {value:g}" for name, value in (("n", sample.n), ("g", sample.g))
                           if value is not None)
        lines.append(f"sample       {stated} (stated; the layer inversion takes them)")
    diagonal = effective_max_radius(manifest)
    if manifest.max_radius is not None:
        lines.append(f"max radius   {manifest.max_radius:g} grid steps")
    else:
        lines.append(
            f"max radius   not set (one point per frame): up to the grid diagonal {diagonal:.1f}, "
            "or the largest radius a stack asks for"
        )
    lines += plan_open(manifest, radius).lines()
    truth = manifest.ground_truth
    if truth is None:
        lines.append("ground truth none")
    else:
        images = truth.path_length_images
        if images:
            lines.append(
                f"ground truth {len(images)} path-length images over "
                f"[{min(i.min for i in images):g}, {max(i.max for i in images):g}) grid steps"
            )
        for layer in truth.layers:
            rgb = ", ".join(f"{v:.3f}" for v in layer.rgb)
            lines.append(f"  layer      {layer.name}: depth {layer.depth[0]:g}-{layer.depth[1]:g}, rgb ({rgb})")
    measure = simulated_measure(manifest)
    if simulated_before_camera_measure(manifest):
        lines.append("measure      exitance: simulated before ringlight scored camera radiance; re-simulate it")
    elif measure is not None:
        lines.append(f"measure      {measure} (simulated)")
    if manifest.notes:
        lines.append("notes        " + "\n             ".join(manifest.notes.splitlines()))
    return lines
