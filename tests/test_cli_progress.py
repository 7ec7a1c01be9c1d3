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


def test_progress_lines_reach_stderr_by_default_off_a_terminal():
    """Issue 39: simulate and layers --method inverse printed nothing for minutes in a batch job
    (the lines needed RINGLIGHT_LOG=info); RINGLIGHT_LOG=warning still silences them."""
    environment = {key: value for key, value in os.environ.items() if key != "RINGLIGHT_LOG"}
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120,
                            env=environment, check=True)
    assert sum("ringlight: opening" in line for line in result.stderr.splitlines()) == 11, result.stderr
    quiet = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120,
                           env={**environment, "RINGLIGHT_LOG": "warning"}, check=True)
    assert "opening" not in quiet.stderr


def test_slow_work_logs_a_line_at_least_every_heartbeat(monkeypatch, caplog):
    """Within a 10 % step, a line after HEARTBEAT_S of silence (a clock set by the test)."""
    from ringlight.app.cli import progress as module

    clock = [0.0]
    monkeypatch.setattr(module, "monotonic", lambda: clock[0])
    caplog.set_level("INFO", logger="ringlight")
    with module.progress_bar("fitting layers") as progress:
        for seconds, fraction in ((1, 0.01), (30, 0.02), (61.5, 0.03), (100, 0.04), (130, 0.05)):
            clock[0] = seconds
            progress(fraction)
    lines = [record.getMessage() for record in caplog.records]
    assert lines == ["fitting layers:   1%", "fitting layers:   3%", "fitting layers:   5%"], lines
