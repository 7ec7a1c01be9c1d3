"""Entry point of the ``ringlight`` console script.

``ringlight COMMAND ...`` runs a command-line tool (no Qt is imported); anything else opens the
explorer window: ``ringlight [DATASET] [--screenshot FILE.png [--radius R] [--pick Y,X]]``.
"""

from __future__ import annotations

import argparse
import sys

from . import cli


def build_command_parser() -> tuple[argparse.ArgumentParser, list[str]]:
    """The parser of ``ringlight COMMAND ...`` and the command names."""
    parser = argparse.ArgumentParser(
        prog="ringlight",
        description="Variable ring light imaging: transient images of subsurface light transport.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    cli.add_commands(subparsers)
    return parser, list(subparsers.choices)


def build_window_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ringlight",
        description="Open the ringlight explorer on DATASET (default: the bundled demo dataset).",
        epilog="Commands (ringlight COMMAND --help): " + ", ".join(build_command_parser()[1]),
    )
    parser.add_argument("dataset", nargs="?", help="dataset folder or its dataset.json")
    parser.add_argument("--screenshot", metavar="FILE.png", help="render the window offscreen to FILE.png and exit")
    parser.add_argument("--radius", type=float, default=None, help="with --screenshot: radius to show (grid steps)")
    parser.add_argument("--pick", default=None, metavar="Y,X", help="with --screenshot: pixel to pick")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command_parser, commands = build_command_parser()
    if argv and argv[0] in commands:
        args = command_parser.parse_args(argv)
        return cli.run_handler(args.handler, args)
    parser = build_window_parser()
    args = parser.parse_args(argv)
    from . import gui  # Qt is imported only for the window

    return gui.run(parser, args)


if __name__ == "__main__":
    sys.exit(main())
