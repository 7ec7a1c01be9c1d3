"""``ringlight capture``: the capture wizard's steps without the window, for scripted rigs."""

from __future__ import annotations

import dataclasses
import sys

from ringlight.core.capture.hardware import OptionError, discover_plugins, make_device, open_pair, parse_options
from ringlight.core.capture.scan import Scan
from ringlight.core.capture.scan_folder import check_scan_folder
from ringlight.core.capture.multiplex import s_matrix
from ringlight.core.capture.scan_plan import ScanError, estimate_disk
from ringlight.core.dataset.memory import format_bytes
from ringlight.core.capture.workflow import (
    camera_notes,
    estimated_seconds,
    measure_correspondence,
    plan_scan,
    resume_scan,
    run_scan,
)
from ringlight.core.colour.regions import parse_rectangle
from ringlight.core.rings.radii import MAX_RING_REACH

from .progress import progress_bar


def add_arguments(capture) -> None:
    """Add the arguments of ``ringlight capture`` to its parser, with its handler."""
    capture.add_argument("--list", action="store_true", help="list the cameras and projectors of every plugin and exit")
    capture.add_argument("--camera", help="camera name (see --list)")
    capture.add_argument("--projector", help="projector name (see --list)")
    capture.add_argument("--roi", metavar="Y0,X0,Y1,X1", help="projector pixels to scan, end exclusive (default: all)")
    capture.add_argument("--max-radius", type=float, default=8.0, help="grid steps (default 8)")
    capture.add_argument("--out", help="dataset folder (new, or an unfinished scan with --resume)")
    capture.add_argument("--resume", action="store_true", help="continue the unfinished scan in --out")
    capture.add_argument("--multiplex", type=int, default=0, metavar="N",
                         help="capture blocks of N lattice frames through a Hadamard S-matrix code "
                              "(N = 7, 15, 31, ...; default 0: one lattice frame per capture)")
    capture.add_argument("--option", action="append", metavar="KEY=VALUE", help="option for both devices")
    capture.add_argument("--camera-option", action="append", metavar="KEY=VALUE")
    capture.add_argument("--projector-option", action="append", metavar="KEY=VALUE")
    capture.set_defaults(handler=run_capture)


def run_capture(args) -> int:
    discovery = discover_plugins()
    if args.list:
        return list_devices(discovery)
    check_arguments(args, discovery)
    roi = parse_rectangle(args.roi) if args.roi else None  # a malformed --roi before the correspondence
    # The output before any device opens: a refusal after the correspondence cost a rig's time.
    scan = resume_scan(args.out) if args.resume else None
    if not args.resume:
        check_scan_folder(args.out)
    camera, projector = open_devices(args, discovery)
    try:
        if scan is None:
            scan = plan_new_scan(args, camera, projector, roi)
        else:
            print(f"resuming {args.out}: {len(scan.finished_frames())} of {len(scan.frames)} frames captured")
        with progress_bar("scanning") as progress:
            out = run_scan(scan, camera, projector, args.resume,
                           lambda state: progress(state.done / state.total))
    except KeyboardInterrupt:
        done = len(scan.finished_frames()) if scan is not None else 0
        print(f"ringlight: interrupted after {done} frames; continue with --resume", file=sys.stderr)
        return 130
    finally:
        projector.close()
        camera.close()
    print(f"wrote {out}: {len(scan.frames)} frames; open it with: ringlight {out}")
    return 0


def list_devices(discovery) -> int:
    """``--list``: the cameras and projectors, and a warning per plugin that did not load."""
    for name, reason in discovery.failures:
        print(f"warning: hardware plugin {name} skipped: {reason}", file=sys.stderr)
    print("cameras     " + ", ".join(sorted(discovery.cameras())))
    print("projectors  " + ", ".join(sorted(discovery.projectors())))
    return 0


def check_arguments(args, discovery) -> None:
    """Refuse, before any device opens, a missing argument, a device that is not there, a
    multiplex order without a code or a --max-radius out of range."""
    absent = [flag for flag, value in (("--camera", args.camera), ("--projector", args.projector), ("--out", args.out))
              if not value]
    if absent:
        raise ScanError(f"capture needs {', '.join(absent)} (see ringlight capture --list for device names)")
    # A plugin that did not load is told where it matters: in the list, and when the device asked
    # for is not there (every capture of the simulated rig began with a warning about FLIR's SDK).
    skipped = [f"hardware plugin {name} skipped: {reason}" for name, reason in discovery.failures]
    for option, name, factories in (("--camera", args.camera, discovery.cameras()),
                                    ("--projector", args.projector, discovery.projectors())):
        if name not in factories:
            raise ScanError("; ".join([f"{option} {name!r}: no such device (available: "
                                       f"{', '.join(sorted(factories)) or 'none'})", *skipped]))
    if args.multiplex:
        s_matrix(args.multiplex)  # refuses an order that has no code before any device opens
    if not 0 < args.max_radius <= MAX_RING_REACH:  # 1e308 overflowed the lattice spacing after the correspondence
        raise ScanError(f"--max-radius must be > 0 and at most {MAX_RING_REACH:g} grid steps, "
                        f"got {args.max_radius:g}")


def open_devices(args, discovery):
    """The camera and the projector, each made with --option under its own options, then opened as a
    pair (:func:`~ringlight.core.capture.hardware.open_pair`: a simulated rig is simulated then, its
    progress shown)."""
    shared = parse_options(args.option)
    camera_options = parse_options(args.camera_option)
    projector_options = parse_options(args.projector_option)
    with progress_bar(f"Opening {args.camera} and {args.projector}") as progress:
        camera = make_named(discovery.cameras(), args.camera, shared, "--camera-option", camera_options, progress)
        projector = make_named(discovery.projectors(), args.projector, shared, "--projector-option",
                               projector_options, progress)
        open_pair(camera, projector)
    return camera, projector


def make_named(factories, name: str, shared: dict[str, str], flag: str, own: dict[str, str], progress):
    """``make_device`` with the ``shared`` options (--option) under the device's ``own`` (given with
    ``flag``); an option value the device refuses is named as the user gave it (``--option size=0x0``)."""
    try:
        return make_device(factories, name, {**shared, **own}, progress)
    except OptionError as error:
        flag, given = (flag, own) if error.key in own else ("--option", shared)
        if error.key not in given:  # a value the factory chose itself: its own message says so
            raise
        raise ScanError(f"{flag} {error.key}={given[error.key]}: {error.problem}") from None


def plan_new_scan(args, camera, projector, roi) -> Scan:
    """Correspondence, plan and disk check of a new scan into ``args.out`` (printed as they come)."""
    with progress_bar("Gray code correspondence") as progress:
        correspondence = measure_correspondence(camera, projector, progress)
    print(f"correspondence: {correspondence.inliers} camera pixels fit a homography, "
          f"residual {correspondence.residual_rms:.2f} projector pixels rms")
    height, width = projector.size
    planned = plan_scan(camera, projector, correspondence, roi or (0, 0, height, width), args.max_radius)
    plan = dataclasses.replace(planned.plan, multiplex=args.multiplex)
    needed, free = estimate_disk(plan, planned.mapping.shape[:2], args.out)
    print(f"plan: {plan.grid_shape[0]} x {plan.grid_shape[1]} grid, spacing {plan.spacing}, "
          f"{len(plan.frames())} frames instead of {plan.grid_shape[0] * plan.grid_shape[1]}, exposures "
          f"{', '.join(f'{e:.3g}' for e in plan.exposures)} s"
          f"{f', Hadamard code of {plan.multiplex}' if plan.multiplex else ''}; about "
          f"{estimated_seconds(planned, projector):.0f} s, "
          f"{format_bytes(needed)} ({format_bytes(free)} free)")
    if needed > free:
        raise ScanError(f"{args.out}: the scan needs about {format_bytes(needed)}, only {format_bytes(free)} are free")
    return Scan(args.out, plan, planned.mapping, camera_notes(camera))
