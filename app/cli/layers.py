"""``ringlight layers``: layer colours, by the paper's methods (transient images at picked radii) or
by inversion (a layered model fitted to the region's ring-light profiles, with uncertainty)."""

from __future__ import annotations

from dataclasses import replace

from ringlight.core import RinglightError, load_manifest, open_dataset
from ringlight.core.atomic import check_output_file
from ringlight.core.colour.chroma import METHODS, require_colour
from ringlight.core.colour.image_export import write_text
from ringlight.core.colour.layer_report import (
    analyse_layers,
    analysis_json,
    analysis_stack_request,
)
from ringlight.core.colour.regions import full_region, parse_rectangle, rectangle_region
from ringlight.core.dataset.frames import dataset_channels
from ringlight.core.dataset.writer import refuse_dataset_file
from ringlight.core.device import CHOICES, choose_device
from ringlight.core.phases import phase
from ringlight.core.inversion.settings import (
    DEFAULT_DEPTH,
    DEFAULT_FINAL_PHOTONS,
    DEFAULT_G,
    DEFAULT_PHOTONS,
    MAX_LAYERS,
    N_GRID,
    InversionSettings,
    settings_from_text,
)
from ringlight.core.inversion.limit import TOLERANCE_XY
from ringlight.core.inversion.report import invert_region, inversion_json
from ringlight.core.rings.stack_request import StackRequest

from .progress import progress_bar


INVERSE_ONLY = {"layers": "auto", "boundaries": None, "mus": None, "n": None, "g": None, "depth": DEFAULT_DEPTH,
                "photons": DEFAULT_PHOTONS, "final_photons": DEFAULT_FINAL_PHOTONS, "device": "auto"}
"""The inverse method's options and their defaults (the parser's): given to another method, they
are refused."""
TRANSIENT_ONLY = {"radii": None, "auto": None, "step": 1.0, "dr": 1.0, "thickness": 1.0}
"""The transient images' options (paper and radiance) and their defaults (the parser's): the
inverse method fits the rings at radii 0, 1, 2, ... of thickness 1 and refuses them."""


def add_arguments(layers) -> None:
    """Add the arguments of ``ringlight layers`` to its parser, with its handler."""
    layers.add_argument("dataset", help="dataset folder or its dataset.json")
    pick = layers.add_mutually_exclusive_group()
    pick.add_argument("--radii", metavar="R1,R2,...", help="increasing radii of the stack, one per layer")
    pick.add_argument("--auto", type=int, metavar="N", help="propose N radii (default 3 when --radii is absent)")
    layers.add_argument("--roi", metavar="Y0,X0,Y1,X1", help="rectangle region, end exclusive (default: all pixels)")
    layers.add_argument("--method", choices=(*METHODS, "inverse"), default="paper",
                        help="paper / radiance: chromaticities of transient images at picked radii; inverse: fit a "
                             "layered model to the ring-light profiles, with a two-sigma region per layer")
    inverse = layers.add_argument_group("inverse method")
    inverse.add_argument("--layers", default=INVERSE_ONLY["layers"], metavar="N|auto",
                         help=f"number of layers, or auto to compare 1..{MAX_LAYERS} by BIC (default auto)")
    inverse.add_argument("--boundaries", metavar="B1,B2,...",
                         help="depths (whole grid steps) where layers meet (default: searched down to 8)")
    inverse.add_argument("--mus", metavar="MUS|M1,M2,...",
                         help="scattering coefficient per grid step: one common value, or one per layer with "
                              "--boundaries (default: searched, common or with a base of its own, chosen by BIC)")
    inverse.add_argument("--n", type=float, default=None,
                         help="refractive index of the sample (default: the dataset's sample.n when its manifest "
                              f"states one, else chosen from {', '.join(f'{n:g}' for n in N_GRID)} by chi-square)")
    inverse.add_argument("--g", type=float, default=None,
                         help=f"scattering anisotropy g (default: the dataset's sample.g, else {DEFAULT_G:g})")
    inverse.add_argument("--depth", type=float, default=INVERSE_ONLY["depth"],
                         help=f"modelled thickness in grid steps (default {DEFAULT_DEPTH:g}: a thick sample)")
    inverse.add_argument("--photons", type=int, default=INVERSE_ONLY["photons"],
                         help=f"photons of each white Monte Carlo database a search compares structures with "
                              f"(default {DEFAULT_PHOTONS})")
    inverse.add_argument("--final-photons", type=int, default=INVERSE_ONLY["final_photons"],
                         help="photons of the white run of each structure fitted at the end, tallied in compact "
                              f"cells (default {DEFAULT_FINAL_PHOTONS})")
    inverse.add_argument("--device", choices=CHOICES, default=INVERSE_ONLY["device"],
                         help="run the white Monte Carlo on an NVIDIA GPU (cuda, needs ringlight[cuda]) or the CPU; "
                              "auto (default) takes a usable GPU")
    layers.add_argument("--step", type=float, default=TRANSIENT_ONLY["step"],
                        help="radius spacing of the stack (default 1)")
    layers.add_argument("--dr", type=float, default=TRANSIENT_ONLY["dr"], help="transient step dr (default 1)")
    layers.add_argument("--thickness", type=float, default=TRANSIENT_ONLY["thickness"],
                        help="ring thickness (default 1)")
    layers.add_argument("--json", metavar="OUT", help="write the result as JSON to OUT (a new file)")
    layers.add_argument("--force", action="store_true", help="replace an existing --json file")
    layers.add_argument("--allow-outside", action="store_true",
                       help="read frames that resolve (through symbolic links) outside the dataset folder")
    layers.set_defaults(handler=run_layers)


def parse_radii(text: str) -> list[float]:
    """``"2,5,8"`` -> [2.0, 5.0, 8.0]; checked before any dataset is loaded."""
    try:
        radii = [float(part) for part in text.split(",")]
    except ValueError:
        raise RinglightError(f"--radii {text!r} must be numbers separated by commas, e.g. 2,5,8") from None
    if not all(0 <= r < float("inf") for r in radii) or any(b <= a for a, b in zip(radii, radii[1:])):
        raise RinglightError(f"--radii {text!r} must be finite, non-negative and increase strictly, e.g. 2,5,8")
    return radii


def parse_inversion(args) -> InversionSettings:
    """The inverse method's settings, checked before any dataset is loaded (the device too)."""
    settings = settings_from_text(args.layers, args.boundaries or "", args.mus or "", args.n, args.g, args.depth,
                                  args.photons, args.final_photons)
    return replace(settings, device=choose_device(args.device).kind)


def check_method_options(args) -> None:
    """One line naming the options given that ``args.method`` does not use (they were ignored:
    ``--method paper --layers 2`` reported three layers as if two had been asked for)."""
    inverse = args.method == "inverse"
    unused = TRANSIENT_ONLY if inverse else INVERSE_ONLY
    given = [f"--{name.replace('_', '-')}" for name, default in unused.items() if getattr(args, name) != default]
    if given:
        which = "the paper and radiance methods'" if inverse else "the inverse method's"
        raise RinglightError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} {which}, not --method "
                             f"{args.method}'s: leave {'it' if len(given) == 1 else 'them'} out or choose that method")


def run_layers(args) -> int:
    check_method_options(args)
    radii = parse_radii(args.radii) if args.radii is not None else None  # --radii '' is refused, not --auto
    StackRequest(step=args.step, dr=args.dr, thickness=args.thickness).check_rings()  # before the dataset opens
    settings = parse_inversion(args) if args.method == "inverse" else None
    if args.json is not None:
        if not args.json.strip():
            raise RinglightError("--json needs a file name")
        check_output_file(args.json, args.force, probe=True)  # refused before the dataset is opened
    manifest = load_manifest(args.dataset)
    if args.json is not None:
        refuse_dataset_file(args.json, manifest.folder)
    require_colour(dataset_channels(manifest, args.allow_outside))  # from the first frame's header
    with progress_bar("opening the dataset") as progress:
        dataset = open_dataset(manifest, progress=progress, allow_outside=args.allow_outside)
    if args.roi:
        y0, x0, y1, x1 = parse_rectangle(args.roi)
        region = rectangle_region(dataset.grid_shape, y0, x0, y1, x1)
        description = f"rows {y0}..{y1 - 1}, columns {x0}..{x1 - 1}"
    else:
        region = full_region(dataset.grid_shape)
        description = "all pixels"
    if settings is not None:
        return _run_inverse(args, dataset, region, description, settings)
    request = analysis_stack_request(dataset, args.step, args.dr, args.thickness)
    with progress_bar("computing transient images") as progress:
        analysis = analyse_layers(dataset, region, description, radii=radii, auto=args.auto,
                                  method=args.method, request=request, progress=progress)
    result = analysis.result
    print(f"{dataset.path}: {description}, method {result.method}, radii {', '.join(f'{r:g}' for r in result.radii)}")
    for index, layer in enumerate(result.layers):
        line = (f"layer {index + 1}  r {layer.radius:5g}  xy ({layer.xy[0]:.4f}, {layer.xy[1]:.4f})  "
                f"sRGB #{'%02x%02x%02x' % layer.srgb8}{'' if layer.trusted else '  (untrusted)'}")
        if result.errors is not None and index < len(result.errors):
            name = analysis.truth_names[index]
            line += f"  truth {name} ({result.truth_xy[index][0]:.4f}, {result.truth_xy[index][1]:.4f})  error {result.errors[index]:.4f}"
        print(line)
    for warning in result.warnings:
        print(f"warning: {warning}")
    if args.json:
        write_text(args.json, analysis_json(analysis, str(dataset.path)), overwrite=args.force)
        print(f"wrote {args.json}")
    return 0


def _run_inverse(args, dataset, region, description: str, settings: InversionSettings) -> int:
    def report(fraction: float, what: str) -> None:
        phase(what)  # the fit's own steps name the bar's phase ("reading the frames" stayed on for minutes)
        progress(fraction)

    with progress_bar("fitting layers") as progress:
        result = invert_region(dataset, region, description, settings, report)
    inversion = result.inversion
    print(f"{dataset.path}: {description}, method inverse: {inversion.notes}")
    print(f"fit: chi-square {inversion.chi2:.1f} for {inversion.dof} degrees of freedom, rings used R/G/B "
          f"{'/'.join(str(int(u)) for u in inversion.used)}, {inversion.seconds:.1f} s")
    for index, layer in enumerate(inversion.layers):
        line = (f"layer {index + 1}  depth {layer.top:g}..{layer.bottom:g}  xy ({layer.xy[0]:.4f}, {layer.xy[1]:.4f})"
                f"  2-sigma region {layer.region_width:.3f} wide (the data allow {layer.allowed_width:.3f})"
                f"  sRGB #{'%02x%02x%02x' % layer.swatch}")
        if not layer.determined:
            line += "  NOT DETERMINED"
        if result.errors is not None:
            line += (f"  truth {result.truth_names[index]} ({result.truth_xy[index][0]:.4f}, "
                     f"{result.truth_xy[index][1]:.4f})  error {result.errors[index]:.4f}"
                     f"{'' if result.inside[index] else '  (truth outside the region)'}")
        print(line)
        if not layer.determined:
            print(f"  layer {index + 1}: {layer.reason}")
        if layer.limit:
            print(f"  layer {index + 1}: not determined to {TOLERANCE_XY:g} xy: {layer.limit}")
    if inversion.warning:
        print(f"warning: {inversion.warning}")
    if args.json:
        write_text(args.json, inversion_json(result, str(dataset.path)), overwrite=args.force)
        print(f"wrote {args.json}")
    return 0
