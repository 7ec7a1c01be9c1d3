"""The phases long work names beside its progress: an open band by band, the stacks and noise
(computed or read back), and where the names go (the explorer's job indicator, the command line's
log lines)."""

import os
import subprocess
import sys

import numpy as np
import pytest
from reference import random_impulses, write_dataset
from ringlight.core import open_dataset
from ringlight.core.dataset import response_store
from ringlight.core.dataset.disc import disc_offset_count
from ringlight.core.phases import phase, reporting_phases
from ringlight.core.rings.stack_cache import cached_noise, cached_stacks
from ringlight.core.rings.stack_request import StackRequest

HEIGHT, WIDTH, MAX_RADIUS, TILE = 23, 19, 4.0, 4


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A multiplexed dataset whose store has 4 x 4-point chunks."""
    impulses = random_impulses(np.random.default_rng(3), HEIGHT, WIDTH, support=MAX_RADIUS)
    write_dataset(tmp_path / "ds", HEIGHT, WIDTH, impulses, max_radius=MAX_RADIUS, multiplex=True)
    monkeypatch.setattr(response_store, "CHUNK_BYTES", TILE * TILE * disc_offset_count(MAX_RADIUS) * 12)
    return tmp_path / "ds"


def named(work):
    names = []
    with reporting_phases(names.append):
        work()
    return names


def test_an_out_of_core_open_names_each_band_it_reads_and_writes(folder):
    bands = []
    names = named(lambda: open_dataset(folder, memory_budget_bytes=1,
                                       preview=lambda row0, row1, steady: bands.append((row0, row1))))
    count = len(bands)  # the preview is called once a band, independently of the names
    assert count == -(-HEIGHT // TILE)
    assert names == [f"band {band} of {count}: {what}" for band in range(1, count + 1)
                     for what in ("reading the frames", "writing the store")]
    assert named(lambda: open_dataset(folder, memory_budget_bytes=1)) == []  # a reopen reads no band


def test_an_in_memory_open_names_reading_the_frames_then_writing_the_store_then_reading_it(folder):
    assert named(lambda: open_dataset(folder)) == ["reading the frames", "writing the store"]
    assert named(lambda: open_dataset(folder)) == ["reading the store"]
    assert named(lambda: open_dataset(folder, use_cache=False)) == ["reading the frames"]


def test_the_stacks_and_noise_name_whether_they_are_computed_or_read_back(folder):
    dataset = open_dataset(folder)
    request = StackRequest(stop=2.0)
    saving = "saving the result for the next open"
    assert named(lambda: cached_stacks(dataset, request)) == ["computing the stacks", saving]
    assert named(lambda: cached_noise(dataset, request)) == ["estimating the noise", saving]
    assert named(lambda: cached_stacks(dataset, request)) == ["reading the saved stacks"]
    assert named(lambda: cached_noise(dataset, request)) == ["reading the saved noise estimate"]


def test_phases_go_to_the_reporter_of_their_own_thread_only():
    import threading

    outer, inner = [], []
    with reporting_phases(outer.append):
        phase("a")
        with reporting_phases(inner.append):
            phase("b")
            thread = threading.Thread(target=lambda: phase("from another thread"))
            thread.start()
            thread.join()
        phase("c")
    phase("nobody listens")
    assert (outer, inner) == (["a", "c"], ["b"])  # the other thread's and the last phase went nowhere


def test_the_job_indicator_shows_the_phase_a_job_names(qtbot):
    from PySide6.QtCore import QThreadPool
    from ringlight.widgets.job_indicator import JobIndicator
    from ringlight.widgets.jobs import JobSlot

    pool = QThreadPool()
    slot = JobSlot(pool)
    indicator = JobIndicator(slot)
    qtbot.addWidget(indicator)
    names = []
    slot.phase.connect(names.append)

    def work(progress):
        phase("band 1 of 2: reading the frames")
        progress(0.25)
        phase("band 2 of 2: writing the store")
        return "done"

    with qtbot.waitSignal(slot.finished, timeout=10000):
        slot.start("Opening ds", work)
    assert names == ["band 1 of 2: reading the frames", "band 2 of 2: writing the store"]
    assert indicator.label.text() == "Opening ds: band 2 of 2: writing the store"
    slot.start("Opening another", lambda progress: None)  # a new job shows its own description
    assert indicator.label.text() == "Opening another"
    pool.waitForDone(10000)


SCRIPT = """
import sys
from ringlight.app.cli.progress import configure_logging, progress_bar
from ringlight.core import open_dataset
from ringlight.core.dataset import response_store

response_store.CHUNK_BYTES = 4 * 4 * 49 * 12
configure_logging()
with progress_bar("opening") as progress:
    open_dataset(sys.argv[1], memory_budget_bytes=1, progress=progress)
"""


def test_the_command_line_logs_each_phase_once_when_stderr_is_not_a_terminal(folder):
    assert disc_offset_count(MAX_RADIUS) == 49
    result = subprocess.run([sys.executable, "-c", SCRIPT, str(folder)], capture_output=True, text=True, timeout=120,
                            env={**os.environ, "RINGLIGHT_LOG": "info"}, check=True)
    lines = [line.split("ringlight: ", 1)[1] for line in result.stderr.splitlines() if "ringlight: " in line]
    phases = [line for line in lines if not line.endswith("%")]
    assert phases == [f"opening: band {band} of 6: {what}" for band in range(1, 7)
                      for what in ("reading the frames", "writing the store")], result.stderr
    percentages = [line for line in lines if line.endswith("%")]
    assert percentages[0] == "opening: band 1 of 6: reading the frames:   0%" and percentages[-1] == "opening: band 6 of 6: reading the frames: 100%"
