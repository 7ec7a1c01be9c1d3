"""``ringlight info``: describe an impulse dataset."""

from __future__ import annotations

import sys

from ringlight.core import load_manifest
from ringlight.core.dataset.checks import find_file_problems

from ..dataset_info import describe_dataset

MAX_PROBLEMS_SHOWN = 20
EXIT_FILE_PROBLEMS = 2


def add_arguments(info) -> None:
    """Add the arguments of ``ringlight info`` to its parser, with its handler."""
    info.add_argument("dataset", help="dataset folder or its dataset.json")
    info.add_argument("--allow-outside", action="store_true",
                      help="accept files that resolve (through symbolic links) outside the dataset folder")
    info.set_defaults(handler=run_info)


def run_info(args) -> int:
    manifest = load_manifest(args.dataset)
    lines = describe_dataset(manifest, getattr(args, "allow_outside", False))
    print("\n".join(lines))
    shown, total = find_file_problems(manifest, getattr(args, "allow_outside", False), keep=MAX_PROBLEMS_SHOWN)
    if total:
        more = f" (and {total - len(shown)} more)" if total > len(shown) else ""
        print(f"ringlight: error: {total} file problem(s){more}:", file=sys.stderr)
        for problem in shown:
            print(f"  {problem}", file=sys.stderr)
        return EXIT_FILE_PROBLEMS
    print(f"files        all {len(manifest.referenced_files())} frame, dark and mapping headers checked")
    return 0
