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


def test_the_log_follows_stderr_when_a_command_runs_again_on_another(monkeypatch):
    """Commands run twice in one process (a notebook, a test's captured stderr): the second's lines
    go to the stderr it runs with. The handler kept the first's stream, closed by then, and a
    command's slow-work line became a logging error's traceback (the option fuzz test, with numba's
    cache empty)."""
    import io
    import logging

    from ringlight.app.cli.progress import configure_logging, logger

    level = logger.level
    first, second = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stderr", first)
    monkeypatch.setenv("RINGLIGHT_LOG", "warning")
    try:
        configure_logging()
        logger.warning("first command")
        first.close()
        monkeypatch.setattr(sys, "stderr", second)
        configure_logging()
        logger.warning("second command")
        ours = [handler for handler in logger.handlers if isinstance(handler, logging.StreamHandler)]
        assert len(ours) == 1 and ours[0].stream is second
        assert second.getvalue().endswith(" ringlight: second command\n"), second.getvalue()
        assert second.getvalue().count("\n") == 1
    finally:
        for handler in list(logger.handlers):  # the next command adds its own
            logger.removeHandler(handler)
        logger.setLevel(level)


def fake_clock(monkeypatch):
    from ringlight.app.cli import progress as module

    clock = [0.0]
    monkeypatch.setattr(module, "monotonic", lambda: clock[0])
    return module, clock


def run_steps(module, clock, steps):
    clock[0] = steps[0][0]  # the work starts at the first step's time
    with module.progress_bar("fitting layers") as progress:
        for seconds, fraction in steps:
            clock[0] = seconds
            progress(fraction)


def test_slow_work_logs_a_line_at_least_every_heartbeat(monkeypatch, caplog):
    """With RINGLIGHT_LOG=info: every 10 %, and within a step a line after HEARTBEAT_S of silence
    (a clock set by the test)."""
    module, clock = fake_clock(monkeypatch)
    caplog.set_level("INFO", logger="ringlight")
    run_steps(module, clock, ((1, 0.01), (30, 0.02), (61.5, 0.03), (100, 0.04), (130, 0.05), (131, 0.1)))
    lines = [record.getMessage() for record in caplog.records]
    assert lines == ["fitting layers:   1%", "fitting layers:   3%", "fitting layers:   5%", "fitting layers:  10%"]


def test_work_past_a_minute_says_so_without_being_asked(monkeypatch, caplog):
    """Issue 39: simulate and layers --method inverse printed nothing for minutes in a batch job
    (progress needed RINGLIGHT_LOG=info). At the default level (warning), work shows its progress
    once it has run QUIET_S; a short command's stderr stays its result."""
    module, clock = fake_clock(monkeypatch)
    caplog.set_level("WARNING", logger="ringlight")
    run_steps(module, clock, ((1, 0.0), (20, 0.1), (59, 0.2), (61, 0.25), (70, 0.3), (200, 0.35)))
    lines = [(record.levelname, record.getMessage()) for record in caplog.records]
    assert lines == [("WARNING", "fitting layers:  30%"), ("WARNING", "fitting layers:  35%")], lines
    caplog.clear()
    run_steps(module, clock, ((0, 0.0), (5, 0.5), (9, 1.0)))
    assert caplog.records == []
