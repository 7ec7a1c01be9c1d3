"""``ringlight demo``: write (first run only) and describe the bundled demo dataset, the red-bead sample."""

from __future__ import annotations

from ringlight.core.simulate.samples import DEMO_SAMPLE, sample_dataset, sample_names

from .info import run_info
from .progress import progress_bar


def add_command(subparsers) -> None:
    demo = subparsers.add_parser(
        "demo", help="write (first run only) and describe a bundled sample dataset (the demo: red-bead)",
        description="Write a bundled sample dataset into the user cache (the first time only) and describe it; "
                    "its folder can then be opened with 'ringlight FOLDER'.")
    demo.add_argument("--sample", choices=sample_names(), default=DEMO_SAMPLE, help="which sample (default: %(default)s)")
    demo.set_defaults(handler=run_demo)


def run_demo(args) -> int:
    """Write (once) and describe a bundled sample dataset."""
    with progress_bar(f"writing the {args.sample} sample (first run only)") as progress:
        path = sample_dataset(args.sample, progress=progress)
    args.dataset = str(path)
    return run_info(args)
