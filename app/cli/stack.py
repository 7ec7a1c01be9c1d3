"""``ringlight stack``: compute a ring light or transient stack and export it as EXR."""

from __future__ import annotations

import numpy as np
from ringlight.core import (
    StackError,
    load_manifest,
    needed_radius,
    open_dataset,
    parse_radius_range,
    ring_stack,
    transient_stack,
    write_stack,
)
from ringlight.core.device import CHOICES, choose_device, cpu_device
from ringlight.core.rings.coverage import coverage_warning, ring_coverage
from ringlight.core.rings.interpolate import interpolated_stack
from ringlight.core.rings.radii import check_reach_within
from ringlight.core.rings.stack_io import check_stack_target

from .progress import progress_bar


def add_arguments(stack) -> None:
    """Add the arguments of ``ringlight stack`` to its parser, with its handler."""
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
    stack.add_argument("--interpolate", action="store_true",
                       help="estimate each ring mean by interpolating every pixel's responses in distance "
                            "(for sparsely lit datasets; not the default ring mean of docs/format/dataset.md)")
    stack.add_argument("--out", required=True, help="output folder (new, empty, or an earlier stack)")
    stack.add_argument("--no-cache", action="store_true",
                       help="neither read nor write the dataset's store (the responses must then fit in memory)")
    stack.add_argument("--scheduler", metavar="ADDRESS",
                       help="compute the rings on a running dask.distributed cluster (e.g. tcp://host:8786), one "
                            "task per band of the dataset's store; the dataset folder must be on a file system "
                            "every worker sees at the same path")
    stack.add_argument("--allow-outside", action="store_true",
                       help="read frames that resolve (through symbolic links) outside the dataset folder")
    stack.add_argument("--device", choices=CHOICES, default="auto",
                       help="sum the rings on an NVIDIA GPU (cuda, needs ringlight[cuda]) or the CPU; auto (default) "
                            "takes a usable GPU")
    stack.set_defaults(handler=run_stack)


def run_stack(args) -> int:
    radii = parse_radius_range(args.radii)
    if len(radii) > 1:
        default_step = float(radii[1] - radii[0])
    else:
        default_step = 1.0
    step = args.dr if args.dr is not None else default_step
    reach = needed_radius(radii, args.thickness, step if args.kind == "transient" else 0.0, args.antialias)
    if args.dr is not None and args.kind == "ring":
        raise StackError("--dr is the transient step (T_r = E_r - E_{r+dr}): it applies to --kind transient, "
                         "not ring")
    if args.interpolate and args.antialias:
        raise StackError("--interpolate estimates the default ring mean; it cannot be combined with --antialias")
    if args.scheduler and (args.no_cache or args.interpolate):
        raise StackError("--scheduler reads the dataset's store band by band: it cannot be combined with "
                         + ("--no-cache" if args.no_cache else "--interpolate"))
    if args.device == "cuda" and (args.scheduler or args.interpolate):
        raise StackError("--device cuda sums the default rings here: it cannot be combined with "
                         + ("--scheduler" if args.scheduler else "--interpolate"))
    device = cpu_device() if args.scheduler or args.interpolate else choose_device(args.device)
    check_stack_target(args.out)  # refused before anything is computed
    manifest = load_manifest(args.dataset)
    if not args.interpolate and manifest.max_radius is not None:
        # Refused before the frames are read (a 100 000-frame dataset was opened first, 25 s).
        check_reach_within(manifest.folder, manifest.max_radius, radii, step if args.kind == "transient" else 0.0,
                           args.thickness, args.antialias)
    with progress_bar("opening the dataset (frames, then its store)") as progress:
        dataset = open_dataset(manifest, radius=reach, use_cache=not args.no_cache, progress=progress,
                               allow_outside=args.allow_outside)
    with progress_bar("computing rings") as progress:
        if args.interpolate:
            stack = interpolated_stack(dataset, radii, args.kind, step, args.thickness)
        elif args.kind == "ring":
            stack = ring_stack(dataset, radii, args.thickness, args.antialias, progress=progress,
                               scheduler=args.scheduler, device=device)
        else:
            stack = transient_stack(dataset, radii, step, args.thickness, args.antialias, progress=progress,
                                    scheduler=args.scheduler, device=device)
    coverage = ring_coverage(dataset, radii, args.thickness)
    with progress_bar("writing EXR") as progress:
        folder = write_stack(stack, args.out, progress=progress, coverage=coverage)
    undefined = int(np.count_nonzero(np.isnan(stack.images).any(-1)))
    print(
        f"wrote {len(radii)} {args.kind} images ({dataset.grid_shape[0]} x {dataset.grid_shape[1]}) to "
        f"{folder}; {undefined} pixel(s) undefined (NaN)"
        + ("; ring means interpolated in distance" if args.interpolate else "")
        + ("" if args.scheduler else f"; rings summed on {device.name}")
    )
    if (warning := coverage_warning(coverage)) is not None:
        print(f"warning: {warning}")
    return 0
