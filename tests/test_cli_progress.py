"""The command-line tools' progress when stderr is not a terminal: log lines, one every 10 %."""

import os
import subprocess
import sys

SCRIPT = """
from ringlight.app.cli.progress import configure_logging, progress_bar
from ringlight.core.dataset.exr_header import quiet_library

configure_logging()
with progress_bar("opening") as progress:
    for step in range(11):
        if step % 2:  # as a reader thread decoding a frame would: descriptor 2 points at /dev/null
            with quiet_library():
                progress(step / 10)
        else:
            progress(step / 10)
"""


def test_progress_lines_reach_stderr_while_the_exr_library_is_silenced():
    """Frames decode back to back in reader threads during an open, each with descriptor 2 pointed
    at /dev/null to silence the OpenEXR library: every progress line must still arrive (three of
    eleven were lost in a 256 px open when they went through descriptor 2)."""
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120,
                            env={**os.environ, "RINGLIGHT_LOG": "info"}, check=True)
    percentages = [line.rsplit(" ", 1)[-1] for line in result.stderr.splitlines() if "ringlight: opening" in line]
    assert percentages == [f"{10 * step}%" for step in range(11)], result.stderr
