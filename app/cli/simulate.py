"""``ringlight simulate``: render a scene (preset or JSON) into an impulse dataset by Monte Carlo."""

from __future__ import annotations

from ringlight.core.dataset.writer import check_dataset_target
from ringlight.core.simulate.presets import load_scene, preset_names, preset_notes
from ringlight.core.simulate.scene import SceneError
from ringlight.core.simulate.transport import simulate_transport, write_transport

from .progress import progress_bar


def add_command(subparsers) -> None:
    simulate = subparsers.add_parser(
        "simulate", help="render a scene (preset or JSON) into an impulse dataset by Monte Carlo"
    )
    simulate.add_argument("scene", nargs="?", help="preset name (see --list) or scene JSON file")
    simulate.add_argument("--out", help="output dataset folder")
    simulate.add_argument("--photons", type=int, default=None, help="photons per lit point and channel")
    simulate.add_argument("--size", default=None, metavar="HxW", help="grid size, e.g. 32x32 (shapes scale)")
    simulate.add_argument("--seed", type=int, default=None, help="random seed (default: the scene's)")
    simulate.add_argument("--overwrite", action="store_true",
                          help="replace an earlier dataset at --out (only if the folder holds nothing else)")
    simulate.add_argument("--list", action="store_true", help="list the bundled presets and exit")
    simulate.set_defaults(handler=run_simulate)


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
    check_dataset_target(args.out, overwrite=args.overwrite)  # refused before simulating
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
