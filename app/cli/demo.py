"""``ringlight demo``: make (first run only) and describe the bundled demo dataset."""

from __future__ import annotations

from ringlight.core.simulate.presets import ensure_demo_dataset

from .info import run_info
from .progress import progress_bar


def add_command(subparsers) -> None:
    demo = subparsers.add_parser("demo", help="make (first run only) and describe the bundled demo dataset")
    demo.set_defaults(handler=run_demo)


def run_demo(args) -> int:
    """Make (once) and describe the bundled demo dataset."""
    with progress_bar("making the demo dataset (first run only)") as progress:
        path = ensure_demo_dataset(progress=progress)
    args.dataset = str(path)
    return run_info(args)
