"""Entry point of the ``ringlight`` console script.

``ringlight COMMAND ...`` runs a command-line tool (no Qt is imported); anything else opens the
explorer window: ``ringlight [DATASET] [--screenshot FILE.png [--radius R] [--pick Y,X]]``.
"""

from __future__ import annotations

import argparse
import ctypes.util
import difflib
import os
import sys
from pathlib import Path

EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT, as a shell reports a process it ended)."""
EXIT_BROKEN_PIPE = 141
"""Exit status when the output's reader went away (128 + SIGPIPE, as ``git log | head``)."""


def build_command_parser(command: str) -> argparse.ArgumentParser:
    """The parser of ``ringlight COMMAND ...`` that runs ``command``: the other commands' parsers
    hold no arguments (:func:`.cli.add_commands`)."""
    from . import cli

    parser = argparse.ArgumentParser(
        prog="ringlight",
        description="Variable ring light imaging: transient images of subsurface light transport.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    cli.add_commands(subparsers, command)
    return parser


def build_window_parser() -> argparse.ArgumentParser:
    from . import cli

    parser = argparse.ArgumentParser(
        prog="ringlight",
        description="Open the ringlight explorer on DATASET (default: the bundled demo dataset).",
        epilog="Commands (ringlight COMMAND --help): " + ", ".join(cli.COMMANDS),
    )
    parser.add_argument("dataset", nargs="?", help="dataset folder or its dataset.json")
    parser.add_argument("--screenshot", metavar="FILE.png", help="render the window offscreen to FILE.png and exit")
    parser.add_argument("--radius", type=float, default=None, help="with --screenshot: radius to show (grid steps)")
    parser.add_argument("--pick", default=None, metavar="Y,X", help="with --screenshot: pixel to pick")
    parser.add_argument("--overwrite", action="store_true", help="with --screenshot: replace an existing FILE.png")
    return parser


def main(argv: list[str] | None = None) -> int:
    """The ``ringlight`` console script; returns its exit status.

    ``ringlight`` and its commands import nothing heavy before this runs (the library, numpy,
    numba and Qt are imported inside it), so that a Ctrl-C at any moment after the interpreter's
    start is one line and status 130, not a traceback of the import it interrupted; a Ctrl-C that
    reaches a compiled kernel (numba's dispatcher then raises SystemError with the interrupt as its
    context) too. A closed output pipe (``ringlight info DATASET | head -1``) ends quietly with 141."""
    try:
        return _main(argv)
    except BaseException as error:
        if _interrupted(error):
            print("ringlight: interrupted; nothing was written", file=sys.stderr)
            return EXIT_INTERRUPTED
        if isinstance(error, BrokenPipeError):
            try:  # the interpreter's last flush of stdout would fail again, printing a warning
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):  # stdout is not a file (a test's capture)
                pass
            return EXIT_BROKEN_PIPE
        raise


def _interrupted(error: BaseException | None) -> bool:
    """True when ``error`` is a KeyboardInterrupt or was raised while handling one."""
    for _ in range(16):  # an exception's chain of causes and contexts, which Python keeps acyclic
        if error is None:
            return False
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


def _main(argv: list[str] | None) -> int:
    from . import cli

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in cli.COMMANDS:
        args = build_command_parser(argv[0]).parse_args(argv)
        return cli.run_handler(args.handler, args)
    parser = build_window_parser()
    args = parser.parse_args(argv)
    problem = _dataset_problem(args.dataset, list(cli.COMMANDS)) or (None if args.screenshot else display_problem())
    if problem:
        print(f"ringlight: error: {problem}", file=sys.stderr)
        return cli.EXIT_USER_ERROR
    from . import gui  # Qt is imported only for the window

    return gui.run(parser, args)


def _dataset_problem(dataset: str | None, commands: list[str]) -> str | None:
    """Why ``dataset`` cannot be opened before any window appears (a typo of a command, say)."""
    if dataset is None or Path(dataset).exists():
        return None
    close = difflib.get_close_matches(dataset, commands, n=1)
    hint = f"; did you mean 'ringlight {close[0]}'?" if close else f" (commands: {', '.join(commands)})"
    return f"{dataset}: no such dataset folder or command{hint}"


XCB_LIBRARIES = {"xcb-cursor": "libxcb-cursor0", "xcb-icccm": "libxcb-icccm4", "xcb-keysyms": "libxcb-keysyms1",
                 "xcb-image": "libxcb-image0", "xcb-render-util": "libxcb-render-util0", "xcb-xkb": "libxcb-xkb1",
                 "xkbcommon-x11": "libxkbcommon-x11-0", "xcb-shape": "libxcb-shape0", "xcb-randr": "libxcb-randr0"}
"""The X11 libraries Qt's xcb platform plugin loads (``ldd libqxcb.so``, PySide6 6.11) that a bare
Debian or Ubuntu lacks, each with its Debian/Ubuntu package."""


def display_problem() -> str | None:
    """Why Qt could not open a window here, in one line, or None.

    Without a display, or on X11 without one of :data:`XCB_LIBRARIES`, Qt aborts the process with a
    misleading message; this is checked first (Linux only; other systems always have a display),
    whenever the platform Qt would use needs a display server: xcb (X11), wayland, or the one Qt
    picks itself when ``QT_QPA_PLATFORM`` is unset.
    """
    if not sys.platform.startswith("linux"):
        return None
    requested = os.environ.get("QT_QPA_PLATFORM", "")
    plugins = _platform_plugins(requested)
    if any(not _needs_display_server(plugin) for plugin in plugins):
        return None  # offscreen, eglfs, vnc, ...: drawn without a display server (or Qt falls back to it)
    x11 = bool(os.environ.get("DISPLAY")) and (not plugins or "xcb" in plugins)
    wayland = bool(os.environ.get("WAYLAND_DISPLAY")) and (not plugins or any(p != "xcb" for p in plugins))
    if not x11 and not wayland:
        if plugins:
            needed = " or ".join(dict.fromkeys("DISPLAY" if p == "xcb" else "WAYLAND_DISPLAY" for p in plugins))
            why = f"QT_QPA_PLATFORM={requested} needs {needed}, which is unset"
        else:
            why = "DISPLAY and WAYLAND_DISPLAY are unset"
        return (f"no display to open a window on ({why}); run it on a desktop, "
                "or use --screenshot FILE.png, or the command-line tools (ringlight --help)")
    missing = [name for name in XCB_LIBRARIES if ctypes.util.find_library(name) is None] if not wayland else []
    if missing:
        names = ", ".join(f"lib{name}" for name in missing)
        packages = " ".join(XCB_LIBRARIES[name] for name in missing)
        return (f"Qt needs the X11 librar{'ies' if len(missing) > 1 else 'y'} {names}, not installed (Debian/Ubuntu: "
                f"apt install {packages}; docs/guide/install.md lists them all)")
    return None


def _platform_plugins(requested: str) -> list[str]:
    """The platform plugins ``QT_QPA_PLATFORM`` names, in the order Qt tries them: "wayland;xcb"
    gives both, "xcb:option=value" gives "xcb"; empty when it is unset."""
    return [entry.split(":")[0].strip() for entry in requested.split(";") if entry.split(":")[0].strip()]


def _needs_display_server(plugin: str) -> bool:
    """xcb draws on an X11 server (DISPLAY), the wayland plugins on a Wayland one (WAYLAND_DISPLAY)."""
    return plugin == "xcb" or plugin.startswith("wayland")


if __name__ == "__main__":
    sys.exit(main())
