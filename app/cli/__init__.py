"""The ``ringlight`` command line: one module per sub-command (no Qt is imported here).

Each module has ``add_command(subparsers)``, which registers its parser with a ``handler``;
:func:`run_handler` runs a handler and turns user errors into one line and exit status 2.
"""

from __future__ import annotations

import sys

from ringlight.core import RinglightError

from . import capture, demo, info, layers, optics, simulate, stack
from .progress import configure_logging

EXIT_USER_ERROR = 2


def add_commands(subparsers) -> None:
    """Register every sub-command on an argparse subparsers object, in the order of ``--help``."""
    for command in (info, stack, simulate, layers, optics, capture, demo):
        command.add_command(_Described(subparsers))


class _Described:
    """Adds sub-command parsers whose ``--help`` opens with the line the command list shows."""

    def __init__(self, subparsers):
        self._subparsers = subparsers

    def add_parser(self, name: str, **options):
        options.setdefault("description", options.get("help"))
        return self._subparsers.add_parser(name, **options)


def run_handler(handler, args) -> int:
    """Run a subcommand, turning user errors into one line on stderr and exit status 2."""
    configure_logging()
    try:
        return handler(args)
    except RinglightError as error:
        print(f"ringlight: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as error:
        where = f"{error.filename}: " if error.filename else ""
        print(f"ringlight: error: {where}{error.strerror or error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("ringlight: interrupted; nothing was written", file=sys.stderr)
        return 130
