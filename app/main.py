"""Entry point of the ``ringlight`` console script."""

from __future__ import annotations

import argparse
import sys

from . import cli


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ringlight",
        description="Variable ring light imaging: transient images of subsurface light transport.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    cli.add_commands(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        return cli.run_handler(cli.run_demo, args)
    return cli.run_handler(args.handler, args)


if __name__ == "__main__":
    sys.exit(main())
