"""``ringlight optics``: absorption and reduced scattering maps (mu_a, mu_s') of a homogeneous
half-space fitted to every pixel's ring profile, a region's values and diffuse reflectance R_d at
spatial frequencies, and the calibration of a real rig on a reference."""

from __future__ import annotations

import json
import math
import os

import numpy as np

from ringlight.core import RinglightError, load_manifest, open_dataset
from ringlight.core.atomic import check_output_file
from ringlight.core.colour.image_export import write_text
from ringlight.core.colour.regions import parse_rectangle, rectangle_region
from ringlight.core.dataset.writer import refuse_dataset_file
from ringlight.core.optics.calibration import calibrate, read_calibration, write_calibration
from ringlight.core.device import CHOICES, choose_device
from ringlight.core.optics.map_file import write_maps
from ringlight.core.optics.maps import optical_maps, sample_optics
from ringlight.core.optics.radial import radial_run
from ringlight.core.optics.region import RegionOptics, region_optics
from ringlight.core.optics.table import DEFAULT_PHOTONS, PHOTON_RANGE, check_photons
from ringlight.core.uncertainty_text import with_errors

from .progress import progress_bar


def add_arguments(optics) -> None:
    """Add the arguments of ``ringlight optics`` to its parser, with its handler."""
    optics.add_argument("dataset", help="dataset folder or its dataset.json")
    optics.add_argument("--out", metavar="MAPS.exr",
                        help="write the maps and their standard errors as EXR channels mua.R ... musp.B_se, "
                             "determined.R ... and complete (1 where every ring lies whole on the grid and lit)")
    optics.add_argument("--json", metavar="OUT",
                        help="write the region's values (--roi, default the whole grid) and R_d as JSON")
    optics.add_argument("--mtf", metavar="F1,F2,...", default=None,
                        help="spatial frequencies of R_d in the JSON: cycles per mm when the dataset gives "
                             "grid.pitch_mm, else per grid step (default 0)")
    optics.add_argument("--roi", metavar="Y0,X0,Y1,X1", help="the region of --json, end exclusive (default: all)")
    optics.add_argument("--layers", type=int, choices=(1, 2), default=1,
                        help="2: also fit the region as two layers by the layer inversion (default 1)")
    optics.add_argument("--n", type=float, default=None,
                        help="refractive index (default: the dataset's sample.n)")
    optics.add_argument("--g", type=float, default=None,
                        help="scattering anisotropy (default: the dataset's sample.g, else 0)")
    optics.add_argument("--calibration", metavar="FILE",
                        help="a real rig's calibration file (made with --write-calibration on a reference)")
    calibration = optics.add_argument_group("calibrating a rig on a reference")
    calibration.add_argument("--write-calibration", metavar="FILE",
                             help="DATASET is a scan of a reference: write the rig's calibration to FILE")
    calibration.add_argument("--reference-mua", metavar="A|R,G,B",
                             help="the reference's absorption (per mm with a pitch, else per grid step)")
    calibration.add_argument("--reference-musp", metavar="S|R,G,B", help="the reference's reduced scattering")
    calibration.add_argument("--reference-description", default="", help="what the reference is")
    optics.add_argument("--photons", type=int, default=DEFAULT_PHOTONS,
                        help=f"photons of the white run behind the look-up table, {PHOTON_RANGE[0]} to "
                             f"{PHOTON_RANGE[1]} (default {DEFAULT_PHOTONS})")
    optics.add_argument("--device", choices=CHOICES, default="auto",
                        help="trace the table's white run on an NVIDIA GPU (cuda, needs ringlight[cuda]) or the CPU; "
                             "auto (default) takes a usable GPU")
    optics.add_argument("--force", action="store_true", help="replace existing output files")
    optics.add_argument("--allow-outside", action="store_true",
                        help="read frames that resolve (through symbolic links) outside the dataset folder")
    optics.set_defaults(handler=run_optics)


def parse_numbers(text: str, option: str, count: int | None = None) -> list[float]:
    """``"0,0.1"`` -> [0.0, 0.1] (finite, >= 0); one line naming ``option`` otherwise."""
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        raise RinglightError(f"{option} {text!r} must be numbers separated by commas") from None
    if not all(math.isfinite(v) and v >= 0 for v in values) or (count is not None and len(values) not in (1, count)):
        raise RinglightError(f"{option} {text!r} must be finite non-negative numbers"
                             + (f", one or {count}" if count else ""))
    return values


def run_optics(args) -> int:
    if not (args.out or args.json or args.write_calibration):
        raise RinglightError("give --out, --json or --write-calibration: nothing to write")
    check_photons(args.photons)
    mtf = "0" if args.mtf is None else args.mtf
    frequencies_text = [part.strip() for part in mtf.split(",")]
    frequencies = parse_numbers(mtf, "--mtf")
    if args.write_calibration and (args.reference_mua is None or args.reference_musp is None):
        raise RinglightError("--write-calibration needs the reference's --reference-mua and --reference-musp")
    if not args.write_calibration and (args.reference_mua is not None or args.reference_musp is not None
                                       or args.reference_description):
        raise RinglightError("--reference-mua, --reference-musp and --reference-description describe the reference "
                             "of --write-calibration: give it, or leave them out")
    if (args.roi or args.layers != 1 or args.mtf is not None) and not args.json:
        raise RinglightError("--roi, --layers and --mtf are for the region of --json: give it, or leave them out")
    rectangle = parse_rectangle(args.roi) if args.roi else None
    reference = (parse_numbers(args.reference_mua, "--reference-mua", 3),
                 parse_numbers(args.reference_musp, "--reference-musp", 3)) if args.write_calibration else None
    outputs = [path for path in (args.out, args.json, args.write_calibration) if path is not None]
    for path in outputs:
        if not path.strip():
            raise RinglightError("an output file needs a name")
        check_output_file(path, args.force, probe=True)  # refused before the work
    if args.out is not None and not args.out.lower().endswith(".exr"):
        raise RinglightError(f"{args.out}: the maps are written as OpenEXR: give a name ending in .exr")
    if len({os.path.realpath(path) for path in outputs}) < len(outputs):
        raise RinglightError(f"{', '.join(outputs)}: two outputs name the same file; give each its own")
    calibration = read_calibration(args.calibration) if args.calibration else None
    device = choose_device(args.device)
    manifest = load_manifest(args.dataset)
    for path in outputs:
        refuse_dataset_file(path, manifest.folder)
    with progress_bar("opening the dataset") as progress:
        dataset = open_dataset(manifest, progress=progress, allow_outside=args.allow_outside)
    # The region is checked against the grid before the white run and the maps, not after them.
    region = None if rectangle is None else rectangle_region(dataset.grid_shape, *rectangle)
    # The tables' white run, read from the user cache or traced here under its own progress bar into
    # it, where the tables below read it (a run of the same photons): a region's fit and a calibration
    # take no progress of their own, and the run is about 50 s at the default photons on two cores.
    with progress_bar(f"white run on {device.name}") as progress:
        radial_run(*sample_optics(dataset, args.n, args.g), args.photons, progress=progress, device=device)
    print(f"white run on {device.name} (or read from the user cache)")
    if reference is not None:
        made = calibrate(dataset, reference[0], reference[1], n=args.n, g=args.g,
                         description=args.reference_description, photons=args.photons)
        write_calibration(args.write_calibration, made, overwrite=args.force)
        print(f"{dataset.path}: rig scale R/G/B {' / '.join(f'{s:.5g}' for s in made.scale)} "
              f"(+- {' / '.join(f'{s:.2g}' for s in made.scale_se)})")
        print(f"wrote {args.write_calibration}")
    if args.out:
        with progress_bar("fitting every pixel") as progress:
            maps = optical_maps(dataset, n=args.n, g=args.g, calibration=calibration, progress=progress,
                                photons=args.photons)
        write_maps(maps, args.out, overwrite=args.force)
        determined, complete = maps.determined.mean() * 100, maps.complete.mean() * 100
        print(f"{dataset.path}: maps in {maps.units.replace('_', ' ')}, n {maps.n:g}, g {maps.g:g}, noise from the "
              f"{maps.noise_source}; {determined:.1f} % of pixel channels determined, {complete:.1f} % of pixels with "
              f"whole rings (channel complete; the others' fits are biased)")
        print(f"wrote {args.out}")
    if args.json:
        result = region_optics(dataset, region, n=args.n, g=args.g, calibration=calibration, layers=args.layers,
                               frequencies=frequencies, photons=args.photons)
        write_text(args.json, json.dumps(region_document(result, frequencies_text, args.roi), indent=1) + "\n",
                   overwrite=args.force)
        units = result.units.replace("_", " ")
        print(f"region: mua {with_errors(result.mua, result.mua_se)}, musp {with_errors(result.musp, result.musp_se)} "
              f"{units} (R / G / B, ±1 SE){result.undetermined_note()}")
        print(f"wrote {args.json}")
    return 0


def region_document(result: RegionOptics, frequencies_text: list[str], roi: str | None) -> dict:
    """The ``--json`` document: the region's values per channel, units, n, g and R_d keyed by each
    asked frequency as written."""
    listed = lambda values: [_number(v) for v in np.asarray(values, float).tolist()]  # noqa: E731
    document = {"mua": listed(result.mua), "musp": listed(result.musp), "mua_se": listed(result.mua_se),
                "musp_se": listed(result.musp_se), "units": result.units, "n": result.n, "g": result.g,
                "R_d": {text: listed(result.reflectance[i]) for i, text in enumerate(frequencies_text)},
                "determined": [bool(d) for d in result.determined], "chi2": listed(result.chi2),
                "rings": len(result.radii), "points": result.points, "region": roi or "all",
                "channels": list(result.channels)}
    if result.layers is not None:
        per = 1.0 / result.pitch_mm if result.pitch_mm else 1.0
        document["layers"] = [{"depth": [layer.top, layer.bottom], "mua": listed(np.asarray(layer.mua) * per),
                               "mua_interval": [listed(row) for row in np.asarray(layer.mua_interval) * per],
                               "musp": _number(layer.mus * per * (1.0 - result.g)),
                               "determined": bool(layer.determined)} for layer in result.layers.layers]
    return document


def _number(value: float):
    return value if math.isfinite(value) else None

