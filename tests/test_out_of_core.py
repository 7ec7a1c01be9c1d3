"""Datasets over the memory budget: built band by band into their store, read from it band by band,
and every result equal bit for bit to the in-memory path (and to brute force)."""

import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
import ringlight.core.dataset.frames as frames_module
from numpy.testing import assert_array_equal
from reference import brute_ring_image, random_impulses, write_dataset
from ringlight.core import open_dataset
from ringlight.core.dataset import response_store
from ringlight.core.dataset.disc import disc_offset_count
from ringlight.core.inversion.measured import measured_profile
from ringlight.core.rings.coverage import ring_coverage
from ringlight.core.rings.interpolate import interpolated_ring_stack
from ringlight.core.rings.noise import stack_noise
from ringlight.core.rings.profiles import pixel_profile, profile_rings
from ringlight.core.rings.stacks import ring_and_transient_stacks, ring_stack

HEIGHT, WIDTH, MAX_RADIUS, TILE = 23, 19, 4.0, 4
RADII = [0, 1, 1.5, 2]


@pytest.fixture
def impulses():
    return random_impulses(np.random.default_rng(3), HEIGHT, WIDTH, support=MAX_RADIUS, missing=0.1)


@pytest.fixture
def folder(tmp_path, impulses, monkeypatch):
    """A multiplexed dataset whose store has 4 x 4-point chunks: six bands of rows."""
    write_dataset(tmp_path / "ds", HEIGHT, WIDTH, impulses, max_radius=MAX_RADIUS, multiplex=True)
    monkeypatch.setattr(response_store, "CHUNK_BYTES", TILE * TILE * disc_offset_count(MAX_RADIUS) * 12)
    return tmp_path / "ds"


def test_over_the_budget_a_dataset_is_read_band_by_band_with_the_same_results(folder, impulses):
    memory = open_dataset(folder, use_cache=False)
    lazy = open_dataset(folder, memory_budget_bytes=1)
    assert memory.in_memory and not lazy.in_memory
    assert lazy.store.tile == TILE and len(lazy.bands()) == 6
    assert_array_equal(lazy.steady_state(), memory.steady_state())
    ring, transient = ring_and_transient_stacks(lazy, RADII)
    ring_memory, transient_memory = ring_and_transient_stacks(memory, RADII)
    assert_array_equal(ring.images, ring_memory.images)
    assert_array_equal(ring.counts, ring_memory.counts)
    assert_array_equal(transient.images, transient_memory.images)
    for index, radius in enumerate(RADII):  # independent: the definition, point by point
        np.testing.assert_allclose(ring.images[index], brute_ring_image(impulses, HEIGHT, WIDTH, radius),
                                   rtol=1e-5, atol=1e-7)
    noise, noise_memory = stack_noise(lazy, RADII), stack_noise(memory, RADII)
    assert_array_equal(noise.transient, noise_memory.transient)
    coverage, coverage_memory = ring_coverage(lazy, RADII), ring_coverage(memory, RADII)
    assert_array_equal(coverage.members, coverage_memory.members)
    assert_array_equal(coverage.nearest_offset, coverage_memory.nearest_offset)
    assert_array_equal(coverage.points, coverage_memory.points)
    assert_array_equal(interpolated_ring_stack(lazy, RADII).images, interpolated_ring_stack(memory, RADII).images)
    for y, x in [(0, 0), (11, 7), (22, 18), (5, 12)]:
        assert_array_equal(lazy.impulse_image(y, x), memory.impulse_image(y, x))
        rings = profile_rings(lazy, RADII, 1.0)
        assert_array_equal(pixel_profile(lazy, rings, (y, x)).transient, pixel_profile(memory, rings, (y, x)).transient)
    region = np.zeros((HEIGHT, WIDTH), bool)
    region[6:17, 4:15] = True
    np.testing.assert_allclose(measured_profile(lazy, region, RADII).mean, measured_profile(memory, region, RADII).mean,
                               rtol=1e-12)


def test_an_out_of_core_build_previews_the_steady_state_band_by_band_before_it_ends(folder, impulses):
    bands = []
    opened = open_dataset(folder, memory_budget_bytes=1, preview=lambda row0, row1, steady: bands.append(
        (row0, row1, steady)))
    assert [(row0, row1) for row0, row1, _ in bands] == [(row, min(row + TILE, HEIGHT)) for row in range(0, HEIGHT, TILE)]
    assert_array_equal(np.concatenate([steady for *_, steady in bands]), opened.steady_state())
    # Independent: the steady state is every impulse summed (all points lit), unobserved points NaN.
    lit = sum(impulses.values())
    observed = np.isfinite(opened.steady_state()).all(-1)
    np.testing.assert_allclose(opened.steady_state()[observed], lit[observed], rtol=1e-5, atol=1e-7)
    reopened = []
    open_dataset(folder, memory_budget_bytes=1, preview=lambda *band: reopened.append(band))
    assert reopened == []  # nothing to build: the stored steady state is shown at once


def test_a_reopen_out_of_core_reads_no_frame_and_no_responses_until_asked(folder, monkeypatch):
    open_dataset(folder, memory_budget_bytes=1)
    decoded = []
    monkeypatch.setattr(frames_module, "read_exr_channels", lambda *args: decoded.append(args))
    reopened = open_dataset(folder, memory_budget_bytes=1)
    assert not decoded and not reopened.in_memory
    assert not reopened.store._bands  # nothing read yet: the steady state is stored
    assert np.isfinite(reopened.steady_state()).all()
    ring_stack(reopened, [1])
    assert len(reopened.store._bands) >= 1


_TRACED_OPEN = """
import sys, tracemalloc
from pathlib import Path
from ringlight.core import open_dataset
from ringlight.core.dataset import response_store

root, budget, response_store.CHUNK_BYTES = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
warm_up = open_dataset(root / "warm-up", memory_budget_bytes=budget)
tracemalloc.start()
lazy = open_dataset(root / "ds", memory_budget_bytes=budget)
print(tracemalloc.get_traced_memory()[1], lazy.in_memory, warm_up.in_memory)
"""


def test_band_assembly_keeps_memory_within_the_budget(tmp_path):
    """A 96 x 80 dataset at max_radius 5 (7.1 MiB of responses) built under a 1 MiB budget: the peak
    of Python allocations stays within the budget plus 2 MiB that any open of it holds whatever
    its budget (the manifest's checks, zarr's metadata and event loop; measured 1.4-2.1 MiB at
    budgets 0.5 to 4 MiB), once a first open has compiled and imported everything (of a dataset a
    quarter as high, also over the budget: the same code on the same types, in a quarter of the
    time).
    Measured in a fresh process: tracing counts every thread's allocations, and a test runner's
    own threads (pytest-xdist's) allocate meanwhile (a 9 MiB peak was seen in one run)."""
    rng = np.random.default_rng(1)
    impulses = random_impulses(rng, 96, 80, support=5)
    write_dataset(tmp_path / "ds", 96, 80, impulses, max_radius=5.0, multiplex=True)
    write_dataset(tmp_path / "warm-up", 24, 80, random_impulses(rng, 24, 80, support=5), max_radius=5.0,
                  multiplex=True)
    size = 96 * 80 * disc_offset_count(5.0) * 12
    budget = 2**20
    # 6 x 6-point chunks: a band is one tile row (6 rows, 0.45 MiB, within the half of the budget
    # a band may take), 16 bands; smaller tiles only add chunk writes (zarr's ~7 CPU-ms each).
    chunk = 6 * 6 * disc_offset_count(5.0) * 12
    result = subprocess.run([sys.executable, "-c", _TRACED_OPEN, str(tmp_path), str(budget), str(chunk)],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    peak, in_memory, warm_up_in_memory = result.stdout.split()
    peak = int(peak)
    assert size > 6 * budget and in_memory == warm_up_in_memory == "False"
    assert peak < budget + 2 * 2**20, f"peak {peak} bytes over the {budget}-byte budget and 2 MiB"
    assert peak < size / 2
    lazy = open_dataset(tmp_path / "ds", memory_budget_bytes=budget)  # the store the child wrote
    assert lazy.store is not None and lazy.store.tile == 6
    assert_array_equal(ring_stack(lazy, [0, 2, 4]).images,
                       ring_stack(open_dataset(tmp_path / "ds", use_cache=False), [0, 2, 4]).images)


def test_without_the_cache_a_dataset_over_the_budget_is_refused_in_one_line(folder):
    from ringlight.core.errors import DatasetError

    with pytest.raises(DatasetError, match="over the memory budget of 1 B, and without the cache there is no store"):
        open_dataset(folder, use_cache=False, memory_budget_bytes=1)


@pytest.mark.allow_leaks("dask.distributed keeps its offload thread (Dask-Offload_0) for the process")
def test_a_local_cluster_of_two_worker_processes_gives_the_in_memory_stack_bit_for_bit(folder):
    from dask.distributed import Client, LocalCluster

    memory = open_dataset(folder, use_cache=False)
    lazy = open_dataset(folder, memory_budget_bytes=1)
    import dask

    # The workers' scratch space in the test's folder (by default dask leaves dask-scratch-space in /tmp).
    with dask.config.set({"temporary-directory": str(folder.parent / "dask-scratch")}), \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            fractions = []
            ring, transient = ring_and_transient_stacks(lazy, RADII, scheduler=client, progress=fractions.append)
        by_address = ring_stack(lazy, RADII, scheduler=cluster.scheduler_address)  # its own client
        # A dataset's first open, in memory, writes its store and keeps it: a stack on the cluster
        # was refused ("open it with the cache on") until the dataset was opened again.
        shutil.copytree(folder, folder.parent / "fresh")
        fresh = open_dataset(folder.parent / "fresh")
        assert fresh.responses is not None  # in memory
        first_open = ring_stack(fresh, RADII, scheduler=cluster.scheduler_address)
    ring_memory, transient_memory = ring_and_transient_stacks(memory, RADII)
    assert_array_equal(ring.images, ring_memory.images)
    assert_array_equal(ring.counts, ring_memory.counts)
    assert_array_equal(transient.images, transient_memory.images)
    assert_array_equal(by_address.images, ring_memory.images)
    assert_array_equal(first_open.images, ring_memory.images)
    assert fractions[-1] == 1.0 and len(fractions) == 6


@pytest.mark.parametrize("address", ["garbage", "tcp://", "127.0.0.1:abc", "inproc://x"])
def test_a_scheduler_address_that_is_no_dask_scheduler_is_one_line(folder, address):
    """Malformed addresses gave dask's ValueError tracebacks (a user review); each failed client
    left its IO loop thread running for the process (the leak guard fails the test on a thread)."""
    from ringlight.core.errors import StackError

    lazy = open_dataset(folder, memory_budget_bytes=1)
    with pytest.raises(StackError, match=f"{re.escape(repr(address))} is not the address of a dask scheduler"):
        ring_stack(lazy, RADII, scheduler=address)


def test_a_scheduler_that_does_not_answer_is_one_line_and_leaves_no_thread(folder, monkeypatch):
    """No scheduler listens on port 1: the client's connection times out, the stack is refused in
    one line, and its IO loop thread ends with it (the leak guard checks)."""
    from ringlight.core.errors import StackError
    from ringlight.core.rings import distributed

    monkeypatch.setattr(distributed, "CONNECT_TIMEOUT_S", 0.5)
    lazy = open_dataset(folder, memory_budget_bytes=1)
    with pytest.raises(StackError, match=re.escape("cannot reach the dask scheduler at tcp://127.0.0.1:1 (")):
        ring_stack(lazy, RADII, scheduler="tcp://127.0.0.1:1")


def test_camera_frames_with_a_dark_frame_and_exposures_give_the_same_bands(tmp_path, impulses, monkeypatch):
    """Camera-space frames (2 x 2 camera pixels a grid point, through mapping.exr), a dark frame
    and exposures other than 1: a band reads each whole camera frame, maps it and cuts its rows;
    the result equals the in-memory open bit for bit."""
    from reference import edit_manifest, write_exr, write_rgb

    monkeypatch.setattr(response_store, "CHUNK_BYTES", TILE * TILE * disc_offset_count(MAX_RADIUS) * 12)
    folder = tmp_path / "camera"
    manifest = write_dataset(folder, HEIGHT, WIDTH, impulses, max_radius=MAX_RADIUS, multiplex=True)
    dark = np.random.default_rng(9).uniform(0.0, 0.01, (2 * HEIGHT, 2 * WIDTH, 3)).astype(np.float32)
    for index, frame in enumerate(manifest["frames"]):
        grid = np.zeros((HEIGHT, WIDTH, 3), np.float32)
        for y, x in frame["lit"]:
            grid += impulses[(y, x)]
        exposure = 0.5 + 0.25 * (index % 3)
        write_rgb(folder / frame["file"], (np.repeat(np.repeat(grid, 2, 0), 2, 1) + dark) * np.float32(exposure))
        frame["exposure"] = exposure
    write_rgb(folder / "dark.exr", dark)
    cy, cx = (np.mgrid[:2 * HEIGHT, :2 * WIDTH].astype(np.float32) - 0.5) / 2  # rounds to (cy // 2, cx // 2)
    write_exr(folder / "mapping.exr", {"y": cy, "x": cx})
    edit_manifest(folder, lambda m: m.update(frames=manifest["frames"], frame_space="camera",
                                             mapping="mapping.exr", dark="dark.exr"))
    memory = open_dataset(folder, use_cache=False)
    lazy = open_dataset(folder, memory_budget_bytes=1)
    assert not lazy.in_memory and len(lazy.bands()) == 6
    assert_array_equal(lazy.steady_state(), memory.steady_state())
    assert_array_equal(ring_stack(lazy, RADII).images, ring_stack(memory, RADII).images)
    np.testing.assert_allclose(ring_stack(memory, [1]).images[0], brute_ring_image(impulses, HEIGHT, WIDTH, 1),
                               rtol=1e-4, atol=1e-5)
