"""``ringlight demo``: write (first run only) and describe the bundled demo dataset, the red-bead sample."""

from __future__ import annotations

from ringlight.core import RinglightError
from ringlight.core.simulate.samples import DEMO_SAMPLE, sample_dataset, sample_names, write_sample

from .info import run_info
from .progress import progress_bar


def add_arguments(demo) -> None:
    """Add the arguments of ``ringlight demo`` to its parser, with its handler."""
    demo.description = ("Write a bundled sample dataset into the user cache (the first time only) and describe it; "
                        "its folder can then be opened with 'ringlight FOLDER'.")
    demo.add_argument("--sample", choices=sample_names(), default=DEMO_SAMPLE, help="which sample (default: %(default)s)")
    demo.add_argument("--out", metavar="DIR",
                      help="write the sample into DIR (a new folder) instead of the user cache, e.g. to try the "
                           "documentation's commands on it (a copy of the user cache's, when it holds the sample)")
    demo.add_argument("--overwrite", action="store_true",
                      help="with --out: replace an earlier dataset there (only if the folder holds nothing else)")
    demo.set_defaults(handler=run_demo)


def run_demo(args) -> int:
    """Write (once, or into ``--out``) and describe a bundled sample dataset."""
    if args.overwrite and args.out is None:
        raise RinglightError("--overwrite replaces a dataset at --out: give --out DIR (the user cache's sample is "
                             "written on its first use)")
    if args.out is not None:
        with progress_bar(f"writing the {args.sample} sample") as progress:
            path = write_sample(args.sample, args.out, overwrite=args.overwrite, progress=progress)
    else:
        with progress_bar(f"writing the {args.sample} sample (first run only)") as progress:
            path = sample_dataset(args.sample, progress=progress)
    args.dataset = str(path)
    return run_info(args)
