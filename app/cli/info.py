"""``ringlight info``: describe an impulse dataset."""

from __future__ import annotations

import sys

import numpy as np
from ringlight.core import DatasetError, effective_max_radius, load_manifest
from ringlight.core.dataset.open_plan import plan_open
from ringlight.core.colourspaces import CUSTOM_PREFIX
from ringlight.core.dataset.checks import check_files
from ringlight.core.dataset.frames import dataset_channels
from ringlight.core.simulate.transport import (
    simulated_before_camera_measure,
    simulated_measure,
)

MAX_PROBLEMS_SHOWN = 20
EXIT_FILE_PROBLEMS = 2


def add_command(subparsers) -> None:
    info = subparsers.add_parser("info", help="describe an impulse dataset")
    info.add_argument("dataset", help="dataset folder or its dataset.json")
    info.add_argument("--allow-outside", action="store_true",
                      help="accept files that resolve (through symbolic links) outside the dataset folder")
    info.set_defaults(handler=run_info)


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


def run_info(args) -> int:
    manifest = load_manifest(args.dataset)
    counts = manifest.lit_counts()
    lit = int(np.count_nonzero(counts))
    missing = counts.size - lit
    pitch = f", pitch {manifest.pitch_mm:g} mm" if manifest.pitch_mm else ""
    points_per_frame = [len(frame.lit) for frame in manifest.frames]
    exposures = sorted({frame.exposure for frame in manifest.frames})
    lines = [
        f"dataset      {manifest.folder}",
        f"grid         {manifest.height} x {manifest.width}{pitch}",
        f"colorspace   {manifest.colorspace.removeprefix(CUSTOM_PREFIX)}",
        f"channels     {_describe_channels(manifest, getattr(args, 'allow_outside', False))}",
        f"frames       {len(manifest.frames)} in {manifest.frame_space} frame space"
        f" ({min(points_per_frame)}-{max(points_per_frame)} lit points per frame;"
        f" exposures {', '.join(f'{e:g}' for e in exposures[:6])}{' ...' if len(exposures) > 6 else ''})",
        f"lit points   {lit} (lit in several frames: {int(np.count_nonzero(counts > 1))})",
        f"missing      {missing} point(s) lit in no frame",
        f"dark frame   {manifest.dark or 'none'}",
    ]
    radius = effective_max_radius(manifest)
    if manifest.max_radius is not None:
        lines.append(f"max radius   {manifest.max_radius:g} grid steps")
    else:
        lines.append(
            f"max radius   not set (one point per frame): up to the grid diagonal {radius:.1f}, "
            "or the largest radius a stack asks for"
        )
    lines += plan_open(manifest).lines()
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
    print("\n".join(lines))
    problems = check_files(manifest, allow_outside=getattr(args, "allow_outside", False))
    if problems:
        shown = problems[:MAX_PROBLEMS_SHOWN]
        more = f" (and {len(problems) - len(shown)} more)" if len(problems) > len(shown) else ""
        print(f"ringlight: error: {len(problems)} file problem(s){more}:", file=sys.stderr)
        for problem in shown:
            print(f"  {problem}", file=sys.stderr)
        return EXIT_FILE_PROBLEMS
    print(f"files        all {len(manifest.referenced_files())} frame, dark and mapping headers checked")
    return 0
