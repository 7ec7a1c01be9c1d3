"""``ringlight simulate``: render a scene (preset or JSON) into an impulse dataset by Monte Carlo."""

from __future__ import annotations

import shutil
import sys
import textwrap

from ringlight.core.dataset.writer import check_dataset_target
from ringlight.core.device import CHOICES, choose_device
from ringlight.core.simulate.presets import load_scene, preset_names, preset_notes
from ringlight.core.simulate.scene import SceneError
from ringlight.core.simulate.progressive import CheckpointError, Status, forget_checkpoint, simulate_until
from ringlight.core.simulate.replicates import MAX_REPLICATES, simulate_replicates
from ringlight.core.simulate.transport import ESTIMATORS, simulate_transport, write_transport

from .progress import progress_bar


MAX_PHOTONS = 10_000_000
"""Photons per lit point and channel the command accepts: ten million already take hours on a
24 x 24 grid (a 20-digit count stopped in numba's typing, 10^12 ran for good and ignored Ctrl+C)."""

MIN_NOISE = 1e-3
"""Smallest --noise target: the noise falls as one over the square root of the photons, so 0.1 %
takes about a million times the photons of 100 %; a target of 1e-320 could never be reached."""


def add_arguments(simulate) -> None:
    """Add the arguments of ``ringlight simulate`` to its parser, with its handler."""
    simulate.add_argument("scene", nargs="?", help="preset name (see --list) or scene JSON file")
    simulate.add_argument("--out", help="output dataset folder")
    simulate.add_argument("--photons", type=int, default=None,
                          help="photons per lit point and channel (with --noise or --time: per batch, default 50)")
    simulate.add_argument("--noise", type=float, default=None, metavar="FRACTION",
                          help="add photons until the estimated relative noise of the transient at the largest "
                               "radius is at most this (e.g. 0.05); resumable: an interrupted run continues "
                               "where it stopped when the same command is given again")
    simulate.add_argument("--time", default=None, metavar="DURATION",
                          help="with or without --noise: stop adding photons after this much simulation "
                               "(e.g. 90s, 10m, 1h)")
    simulate.add_argument("--estimator", choices=ESTIMATORS, default="reference",
                          help="reference: a shift-invariant reference plus correlated differences (default, "
                               "far less noise); analogue: every point's photons on their own")
    simulate.add_argument("--size", default=None, metavar="HxW", help="grid size, e.g. 32x32 (shapes scale)")
    simulate.add_argument("--seed", type=int, default=None, help="random seed (default: the scene's)")
    simulate.add_argument("--replicates", type=int, default=None, metavar="K",
                          help=f"split the photons into K independent runs (2..{MAX_REPLICATES}) written as the "
                               "dataset's replicates, so that its noise, shared by lit points or not, can be "
                               "measured (the standard errors of the explorer and of the layer inversion); "
                               "with --photons, not --noise or --time")
    simulate.add_argument("--device", choices=CHOICES, default="auto",
                          help="where the photons walk: auto (a usable NVIDIA GPU, else the CPU), cpu, or cuda "
                               "(a GPU or stop); see docs/guide/devices.md")
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


BATCH = 50


def parse_duration(text: str) -> float:
    """Seconds of a duration such as ``90``, ``90s``, ``10m`` or ``1.5h``."""
    units = {"s": 1.0, "m": 60.0, "h": 3600.0}
    number, unit = (text[:-1], text[-1]) if text and text[-1].lower() in units else (text, "s")
    try:
        value = float(number) * units[unit.lower()]
        if not value > 0 or value == float("inf"):
            raise ValueError
    except ValueError:
        raise SceneError(f"--time {text!r} must be a positive duration such as 90s, 10m or 1h") from None
    return value


def run_progressive(scene, args, seconds, device):
    """Simulate with :func:`simulate_until`, printing the noise after every pair of batches."""
    def report(status: Status) -> None:
        where = "resumed at" if status.resumed else "at"
        print(f"{where} {status.photons} photons per point: noise of T_r up to r = {status.radius} "
              f"at most {status.worst:.3f}"
              + (f" (target {args.noise})" if args.noise is not None else "")
              + f", {status.seconds:.0f} s", file=sys.stderr, flush=True)

    try:
        with progress_bar(f"simulating {scene.name} (a pair of batches)") as progress:
            transport, status = simulate_until(scene, args.noise, seconds, batch=args.photons or BATCH,
                                               seed=args.seed, estimator=args.estimator, report=report,
                                               progress=progress, device=device)
    except KeyboardInterrupt:
        print("ringlight: interrupted; the photons simulated so far are kept: give the same command to continue",
              file=sys.stderr)
        raise SystemExit(130) from None
    except CheckpointError as error:
        raise SceneError(f"{error}; delete it to start afresh") from None
    if args.noise is not None and status.worst > args.noise:
        print(f"stopped at --time with noise {status.worst:.3f} above the target {args.noise}", file=sys.stderr)
    return transport


def preset_table(presets: list[tuple[str, str]], width: int) -> list[str]:
    """``simulate --list``'s lines: each preset's name in a column as wide as the longest name,
    its notes beside it, wrapped to ``width`` characters under themselves (a fixed 12-character
    column ran "layers-reversed" into its notes)."""
    column = max(len(name) for name, _ in presets) + 2
    lines = []
    for name, notes in presets:
        wrapped = textwrap.wrap(notes, max(width - column, 20)) or [""]
        lines.append(f"{name:<{column}}{wrapped[0]}")
        lines += [" " * column + line for line in wrapped[1:]]
    return lines


def run_simulate(args) -> int:
    if args.list:
        print("\n".join(preset_table([(name, preset_notes(name)) for name in preset_names()],
                                      shutil.get_terminal_size().columns)))
        return 0
    if not args.scene or not args.out:
        raise SceneError("simulate needs a SCENE (preset or JSON file) and --out DIR (or --list)")
    if args.photons is not None and not 0 < args.photons <= MAX_PHOTONS:
        raise SceneError(f"--photons must be 1 to {MAX_PHOTONS:,} per lit point, got {args.photons}")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise SceneError(f"--seed must be 0 to {2**32 - 1}, got {args.seed}")
    if args.noise is not None and not MIN_NOISE <= args.noise < 1:
        raise SceneError(f"--noise must be a fraction from {MIN_NOISE:g} to below 1, e.g. 0.05, got {args.noise}")
    if args.replicates is not None:
        if not 2 <= args.replicates <= MAX_REPLICATES:
            raise SceneError(f"--replicates must be 2 to {MAX_REPLICATES}, got {args.replicates}")
        if args.noise is not None or args.time is not None:
            raise SceneError("--replicates splits a fixed number of photons (--photons): it does not go with "
                             "--noise or --time")
    seconds = parse_duration(args.time) if args.time is not None else None
    scene = load_scene(args.scene, size=parse_size(args.size) if args.size else None)
    check_dataset_target(args.out, overwrite=args.overwrite)  # refused before simulating
    device = choose_device(args.device)
    if args.replicates is not None:
        with progress_bar(f"simulating {scene.name} in {args.replicates} replicates") as progress:
            transport = simulate_replicates(scene, args.photons or scene.photons_per_point, args.replicates,
                                            args.seed, progress, args.estimator, device)
    elif args.noise is None and seconds is None:
        with progress_bar(f"simulating {scene.name}") as progress:
            transport = simulate_transport(scene, photons=args.photons, seed=args.seed, progress=progress,
                                           estimator=args.estimator, device=device)
    else:
        transport = run_progressive(scene, args, seconds, device)
    with progress_bar("writing dataset") as progress:
        write_transport(transport, args.out, overwrite=args.overwrite, progress=progress)
    if args.noise is not None or seconds is not None:
        forget_checkpoint(scene, args.seed, args.photons or BATCH, args.estimator)
    channels = 1 if scene.grey else 3
    total = scene.height * scene.width * transport.photons * channels
    print(
        f"wrote {args.out}: {scene.height} x {scene.width} grid, {total:,} photons in "
        f"{transport.seconds:.1f} s ({total / transport.seconds / 1e6:.2f} M photons/s) on {device.name}"
    )
    return 0
