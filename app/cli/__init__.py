"""The ``ringlight`` command line: one module per sub-command (no Qt is imported here).

:data:`COMMANDS` names each sub-command and its one-line help; its module (``app/cli/NAME.py``)
has ``add_arguments(parser)``, which adds the arguments and a ``handler``. Only the module of the
command being run is imported: each one loads what its work needs (cv2 for capture, the optics
package, the simulator, the inversion), and a command should not pay for the others' (0.4-0.55 s
of CPU at every start, of 1.2-3.7 s for ``simulate --list``, ``info`` and a small ``stack``).
:func:`run_handler` runs a handler and turns user errors into one line and exit status 2 (a
Ctrl-C and a closed output pipe are :func:`ringlight.app.main.main`'s).
"""

from __future__ import annotations

import importlib
import sys

from ringlight.core import RinglightError

from .progress import configure_logging

EXIT_USER_ERROR = 2

COMMANDS = {
    "info": "describe an impulse dataset",
    "stack": "compute a ring light or transient stack and export it as EXR",
    "simulate": "render a scene (preset or JSON) into an impulse dataset by Monte Carlo",
    "layers": "recover layer colours from the chromaticities of transient images (paper Sec. 4.2)",
    "optics": "absorption and reduced scattering maps (mu_a, mu_s') and R_d at spatial frequencies",
    "capture": "capture an impulse dataset with a camera and projector (Gray code, HDR, parallel scan)",
    "demo": "write (first run only) and describe a bundled sample dataset (the demo: red-bead)",
}
"""Sub-command name -> the line ``--help`` lists, in the order of ``--help``; a command's own
``--help`` opens with it too, unless its module sets a longer description."""


def add_commands(subparsers, command: str) -> None:
    """Register every sub-command on an argparse subparsers object; only ``command`` gets its
    arguments and handler, and only its module is imported."""
    for name, summary in COMMANDS.items():
        parser = subparsers.add_parser(name, help=summary, description=summary)
        if name == command:
            importlib.import_module(f"{__name__}.{name}").add_arguments(parser)


def run_handler(handler, args) -> int:
    """Run a subcommand, turning user errors into one line on stderr and exit status 2."""
    configure_logging()
    try:
        return handler(args)
    except RinglightError as error:
        print(f"ringlight: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:
        raise  # the output's reader went away: not the user's error (:func:`ringlight.app.main.main`)
    except OSError as error:
        where = f"{error.filename}: " if error.filename else ""
        print(f"ringlight: error: {where}{error.strerror or error}", file=sys.stderr)
        return EXIT_USER_ERROR
