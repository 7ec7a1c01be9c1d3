"""The ``ringlight`` command line: ``info`` and ``stack`` (no Qt is imported here)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from ringlight.core import (
    RinglightError,
    effective_max_radius,
    needed_radius,
    open_dataset,
    parse_radius_range,
    read_manifest,
    response_memory_bytes,
    ring_stack,
    transient_stack,
    write_stack,
)
from ringlight.core.simulate.presets import ensure_demo_dataset, load_scene, preset_names, preset_notes
from ringlight.core.simulate.scene import SceneError
from ringlight.core.simulate.transport import simulate_transport, write_transport

from . import capture_cli, layers_cli

EXIT_USER_ERROR = 2


def add_commands(subparsers) -> None:
    """Register the core subcommands on an argparse subparsers object."""
    info = subparsers.add_parser("info", help="describe an impulse dataset")
    info.add_argument("dataset", help="dataset folder or its dataset.json")
    info.set_defaults(handler=run_info)

    stack = subparsers.add_parser(
        "stack", help="compute a ring light or transient stack and export it as EXR"
    )
    stack.add_argument("dataset", help="dataset folder or its dataset.json")
    stack.add_argument("--kind", choices=("ring", "transient"), default="transient")
    stack.add_argument(
        "--radii", required=True, metavar="START:STOP:STEP",
        help="ring radii in grid steps, STOP inclusive, e.g. 0:20:1",
    )
    stack.add_argument("--thickness", type=float, default=1.0, help="ring thickness w (default 1)")
    stack.add_argument(
        "--dr", type=float, default=None,
        help="transient step: T_r = E_r - E_{r+dr} (default: the STEP of --radii)",
    )
    stack.add_argument("--antialias", action="store_true", help="weight ring pixels by area")
    stack.add_argument("--out", required=True, help="output folder (new, empty, or an earlier stack)")
    stack.add_argument("--no-cache", action="store_true", help="neither read nor write the packed cache")
    stack.set_defaults(handler=run_stack)

    simulate = subparsers.add_parser(
        "simulate", help="render a scene (preset or JSON) into an impulse dataset by Monte Carlo"
    )
    simulate.add_argument("scene", nargs="?", help="preset name (see --list) or scene JSON file")
    simulate.add_argument("--out", help="output dataset folder")
    simulate.add_argument("--photons", type=int, default=None, help="photons per lit point and channel")
    simulate.add_argument("--size", default=None, metavar="HxW", help="grid size, e.g. 32x32 (shapes scale)")
    simulate.add_argument("--seed", type=int, default=None, help="random seed (default: the scene's)")
    simulate.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --out")
    simulate.add_argument("--list", action="store_true", help="list the bundled presets and exit")
    simulate.set_defaults(handler=run_simulate)

    layers_cli.add_command(subparsers, progress_bar)
    capture_cli.add_command(subparsers, progress_bar)

    demo = subparsers.add_parser("demo", help="make (first run only) and describe the bundled demo dataset")
    demo.set_defaults(handler=run_demo)


@contextmanager
def progress_bar(description: str) -> Iterator[Callable[[float], None]]:
    """A tqdm bar on stderr (shown on terminals only) driven by fractions in [0, 1]."""
    from tqdm import tqdm

    with tqdm(total=1000, desc=description, file=sys.stderr, disable=None, leave=False,
              bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]") as bar:
        def update(fraction: float) -> None:
            bar.update(int(round(fraction * 1000)) - bar.n)
        yield update


def run_info(args) -> int:
    manifest = read_manifest(args.dataset)
    counts = manifest.lit_counts()
    lit = int(np.count_nonzero(counts))
    missing = counts.size - lit
    pitch = f", pitch {manifest.pitch_mm:g} mm" if manifest.pitch_mm else ""
    points_per_frame = [len(frame.lit) for frame in manifest.frames]
    exposures = sorted({frame.exposure for frame in manifest.frames})
    lines = [
        f"dataset      {manifest.folder}",
        f"grid         {manifest.height} x {manifest.width}{pitch}",
        f"colorspace   {manifest.colorspace}",
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
    memory = response_memory_bytes((manifest.height, manifest.width), radius)
    lines.append(f"memory       {memory / 2**20:.1f} MiB of responses at radius {radius:.4g}")
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
    if manifest.notes:
        lines.append(f"notes        {manifest.notes}")
    print("\n".join(lines))
    return 0


def run_stack(args) -> int:
    radii = parse_radius_range(args.radii)
    if len(radii) > 1:
        default_step = float(radii[1] - radii[0])
    else:
        default_step = 1.0
    step = args.dr if args.dr is not None else default_step
    reach = needed_radius(radii, args.thickness, step if args.kind == "transient" else 0.0, args.antialias)
    with progress_bar("reading frames") as progress:
        dataset = open_dataset(args.dataset, radius=reach, use_cache=not args.no_cache, progress=progress)
    with progress_bar("computing rings") as progress:
        if args.kind == "ring":
            stack = ring_stack(dataset, radii, args.thickness, args.antialias, progress=progress)
        else:
            stack = transient_stack(dataset, radii, step, args.thickness, args.antialias, progress=progress)
    with progress_bar("writing EXR") as progress:
        folder = write_stack(stack, args.out, progress=progress)
    undefined = int(np.count_nonzero(np.isnan(stack.images).any(-1)))
    print(
        f"wrote {len(radii)} {args.kind} images ({dataset.grid_shape[0]} x {dataset.grid_shape[1]}) to "
        f"{folder}; {undefined} pixel(s) undefined (NaN)"
    )
    return 0


def parse_size(text: str) -> tuple[int, int]:
    try:
        height, width = (int(v) for v in text.lower().split("x"))
        if height <= 0 or width <= 0:
            raise ValueError
    except ValueError:
        raise SceneError(f"--size {text!r} must be HxW with positive integers, e.g. 32x32") from None
    return height, width


def run_simulate(args) -> int:
    if args.list:
        for name in preset_names():
            print(f"{name:12s} {preset_notes(name)}")
        return 0
    if not args.scene or not args.out:
        raise SceneError("simulate needs a SCENE (preset or JSON file) and --out DIR (or --list)")
    if args.photons is not None and args.photons <= 0:
        raise SceneError(f"--photons must be positive, got {args.photons}")
    if args.seed is not None and args.seed < 0:
        raise SceneError(f"--seed must be >= 0, got {args.seed}")
    scene = load_scene(args.scene, size=parse_size(args.size) if args.size else None)
    if Path(args.out).exists() and not args.overwrite:
        raise SceneError(f"{args.out}: already exists; choose another --out or pass --overwrite")
    with progress_bar(f"simulating {scene.name}") as progress:
        transport = simulate_transport(scene, photons=args.photons, seed=args.seed, progress=progress)
    with progress_bar("writing dataset") as progress:
        write_transport(transport, args.out, overwrite=args.overwrite, progress=progress)
    channels = 1 if scene.grey else 3
    total = scene.height * scene.width * transport.photons * channels
    print(
        f"wrote {args.out}: {scene.height} x {scene.width} grid, {total:,} photons in "
        f"{transport.seconds:.1f} s ({total / transport.seconds / 1e6:.2f} M photons/s)"
    )
    return 0


def run_demo(args) -> int:
    """Make (once) and describe the bundled demo dataset."""
    with progress_bar("making the demo dataset (first run only)") as progress:
        path = ensure_demo_dataset(progress=progress)
    args.dataset = str(path)
    return run_info(args)


def run_handler(handler, args) -> int:
    """Run a subcommand, turning user errors into one line on stderr and exit status 2."""
    try:
        return handler(args)
    except RinglightError as error:
        print(f"ringlight: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as error:
        where = f"{error.filename}: " if error.filename else ""
        print(f"ringlight: error: {where}{error.strerror or error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("ringlight: interrupted; nothing was written", file=sys.stderr)
        return 130
