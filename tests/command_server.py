"""A ``ringlight`` command that starts without paying for its third-party imports again, for the
docs' shell blocks (tests/test_doc_snippets.py).

A page's commands each ran in a new interpreter that imported numpy, numba, SciPy (through
colour-science), OpenCV, OpenEXR and ringlight's core anew: about 1.5-2 of the 2-7 CPU-s a command
costs, on 30-odd commands. Here one server process per test worker imports them once (what the
console script imports before it calls ``main``), and forks a child per command. A ``ringlight``
script placed first on the page's PATH hands the server its arguments, folder, environment and
standard streams (as file descriptors over a Unix socket) and exits with the child's status. The child runs what the
console script runs (``sys.exit(ringlight.app.main.main())``) and ends as an interpreter does
(atexit handlers, flushed streams), so a block sees the same streams, files and exit status.

What it does not see: the console script's own start (its first imports of those libraries and
of ``ringlight.app.main`` with what that imports), which README.md's commands still run
(tests/test_doc_snippets.py's ``COLD``), as do test_cli.py's and test_command_start.py's. A
command's own modules (``ringlight.app.cli.optics`` and what it imports) are not imported before
it, so a command still imports what it needs itself.

Run as ``python command_server.py SOCKET``; it serves until SIGTERM, then waits for the commands
still running and ends.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

PRELOADED = ("numpy", "numba", "scipy.interpolate", "cv2", "OpenEXR")
"""Third-party packages every data command imports; colour-science too, which only the commands
that convert colours import (``layers``), through ringlight's own quiet import. The server can fork after them: numba starts its threads only at a parallel
kernel's first call, which the server never makes, and OpenBLAS (numpy's and SciPy's) stops
its worker threads around a fork (pthread_atfork)."""

CLIENT = """\
#!{python} -I
import json, os, socket, struct, sys
connection = socket.socket(socket.AF_UNIX)
connection.connect({socket_path!r})
request = json.dumps({{"argv": sys.argv, "cwd": os.getcwd(), "env": dict(os.environ)}}).encode()
socket.send_fds(connection, [struct.pack("!I", len(request)) + request], [0, 1, 2])
status = b""
while len(status) < 4 and (chunk := connection.recv(4 - len(status))):
    status += chunk
sys.exit(struct.unpack("!i", status)[0] if len(status) == 4 else 70)
"""
"""The ``ringlight`` script a page's shell blocks find first on PATH (``-I``: only the standard
library; exit 70, EX_SOFTWARE, if the server went away)."""


def _receive(connection: socket.socket) -> tuple[dict, list[int]]:
    """The client's request (argv, cwd, env) and its three standard file descriptors."""
    data, fds, _, _ = socket.recv_fds(connection, 1 << 16, 3)
    while len(data) < 4 or len(data) < 4 + struct.unpack("!I", data[:4])[0]:
        more = connection.recv(1 << 16)
        if not more:
            raise ConnectionError("the client's request ended early")
        data += more
    return json.loads(data[4:]), fds


def _run_command(request: dict, fds: list[int]) -> int:
    """In the forked child: become the client's process (folder, environment, streams) and run the
    console script's ``main``; returns its exit status."""
    import random
    import tempfile

    import numpy as np

    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    tempfile.tempdir = None  # TMPDIR is the page's: found again on first use
    np.random.seed()  # a new process's global stream, not the server's (random reseeds itself at fork)
    random.seed()
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    sys.argv = list(request["argv"])
    from ringlight.app.main import main

    return main()


def serve(socket_path: str) -> None:
    """Import :data:`PRELOADED` and the console script's module, then fork a child per request."""
    import importlib

    for name in PRELOADED:
        importlib.import_module(name)
    from ringlight.core.colourspaces import colour_module

    colour_module()
    import ringlight.app.main  # noqa: F401  (what the console script imports before main)

    listener = socket.socket(socket.AF_UNIX)
    listener.bind(socket_path + ".new")
    listener.listen()
    os.rename(socket_path + ".new", socket_path)  # the client's script connects once this appears
    signal.signal(signal.SIGTERM, _stop)
    sys.stdout.flush()
    sys.stderr.flush()
    while True:
        connection, _ = listener.accept()
        while _reap(os.WNOHANG):
            pass
        request, fds = _receive(connection)
        if os.fork() == 0:
            listener.close()
            _watch(connection, request, fds)
        connection.close()
        for fd in fds:
            os.close(fd)


def _watch(connection: socket.socket, request: dict, fds: list[int]) -> None:
    """In a child of the server: fork the command, wait for it and send the client its status (the
    server goes on serving: a block killed for hanging leaves its command running, not the
    server waiting)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    pid = os.fork()
    if pid == 0:
        connection.close()
        # SystemExit leaves every loop and ends this child as the interpreter ends a script.
        sys.exit(_run_command(request, fds))
    for fd in fds:
        os.close(fd)
    code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    try:
        connection.sendall(struct.pack("!i", 128 - code if code < 0 else code))  # bash's 128 + signal
    except OSError:
        pass  # the client is gone (killed with its block)
    os._exit(0)


def _reap(options: int) -> bool:
    """Wait for one ended child (so its commands' CPU time counts in the server's children's, and
    so in the test run's); False when none is left to wait for (or, WNOHANG, none has ended)."""
    try:
        return os.waitpid(-1, options)[0] != 0
    except ChildProcessError:
        return False


def _stop(signum, frame) -> None:
    """SIGTERM: wait for the commands still running, then end."""
    while _reap(0):
        pass
    os._exit(0)


class CommandServer:
    """A running server and the folder holding its ``ringlight`` script (put it first on PATH)."""

    def __init__(self, folder: Path, python: str = sys.executable):
        self.folder = folder
        self.socket_path = str(folder / "server.sock")
        self.bin = folder / "bin"
        self.bin.mkdir()
        script = self.bin / "ringlight"
        script.write_text(CLIENT.format(python=python, socket_path=self.socket_path), "utf-8")
        script.chmod(0o755)
        # stdout not a terminal, as the shell blocks' captured one is not (Python buffers it alike)
        self.process = subprocess.Popen([python, __file__, self.socket_path], stdin=subprocess.DEVNULL,
                                        stdout=subprocess.DEVNULL)
        deadline = time.monotonic() + 120  # the imports, on a loaded two-core machine
        while not os.path.exists(self.socket_path):
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the command server did not start (exit {self.process.poll()})")
            time.sleep(0.05)

    def close(self) -> None:
        """End the server once its commands have ended."""
        self.process.terminate()
        self.process.wait()


if __name__ == "__main__":
    serve(sys.argv[1])
