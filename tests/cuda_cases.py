"""The CUDA kernels' runs for tests/test_cuda_kernels.py, each saved to an .npz: in this process
when it has a usable GPU, else in a child process under numba's CUDA simulator
(NUMBA_ENABLE_CUDASIM must be set before numba is first imported, and the simulator runs each
thread as a Python thread, which the test process's leak guard would count).

Run as ``python cuda_cases.py FOLDER CASE=ARGUMENT ...``: each case's arrays go to FOLDER/CASE.npz;
exits 3 when the simulator is missing. One process runs every case: a start and its imports cost
about 1 CPU-s, more than most cases' kernels.
"""

from __future__ import annotations

import os
import subprocess
import sys
import traceback
import warnings
from pathlib import Path

import numpy as np

UNAVAILABLE = 3


def radial(out: Path, argument: str) -> None:
    """The radial white run's kernel: 12 photons on 4 streams of seed 3 (n 1.4, g 0.5)."""
    from ringlight.core.optics.radial_cuda import run_radial_cuda

    run = run_radial_cuda(1.4, 0.5, 12, seed=3, streams=4)
    np.savez(out, weight=run.weight, rho=run.rho, path=run.path, photons=run.photons)


def white(out: Path, argument: str) -> None:
    """The layered slab's white run kernel: 256 photons on 4 streams of seed 2, an index-matched
    isotropic slab of mus 1 per grid step, 8 grid steps deep, records within 5 pixels."""
    from ringlight.core.inversion.white_cuda import run_white_cuda
    from ringlight.core.inversion.white_mc import SlabOptics

    run = run_white_cuda(SlabOptics((1.0,), 0.0, 1.0, 8.0, 5), 256, seed=2, streams=4)
    np.savez(out, pixel=run.pixel, value=run.value, lengths=run.lengths, photon=run.photon, photons=run.photons)


CELLS_OPTICS = dict(mus=(1.0, 1.0, 2.0), g=0.5, n=1.0, depth=8.0, reach=3)
"""The slab of the cells case (:func:`cells`): three depth bins, records within 3 pixels."""


def cells(out: Path, argument: str) -> None:
    """The white run tallied in cells on the GPU: 64 photons of seed 5 for two layers (bins 0 and
    1-2) in two launches of 32 on 4 streams, from a table of 16 slots (it grows); and the records
    of each launch's photons by the records kernel (``launch{c}_pixel`` etc.)."""
    from ringlight.core.inversion.cells_cuda import run_cells_cuda
    from ringlight.core.inversion.forward import Structure
    from ringlight.core.inversion.white_cuda import run_white_cuda
    from ringlight.core.inversion.white_mc import SlabOptics

    optics = SlabOptics(**CELLS_OPTICS)
    run = run_cells_cuda(optics, Structure((0, 1)), 64, seed=5, streams=4, slots=16, launch_photons=32)
    arrays = dict(photons=run.photons, cell_class=run.cell_class, weight=run.weight, mean=run.mean,
                  spread=run.spread, batch_weight=run.batch_weight)
    for launch in range(2):
        records = run_white_cuda(optics, 32, seed=5 + (launch << 32), streams=4)
        for name in ("pixel", "value", "lengths", "photon"):
            arrays[f"launch{launch}_{name}"] = getattr(records, name)
    np.savez(out, **arrays)


def stacks(out: Path, argument: str) -> None:
    """The ring and transient stacks of the dataset at ``argument`` (radius 4.5), radii 0..3."""
    from ringlight.core import open_dataset
    from ringlight.core.device import choose_device
    from ringlight.core.rings.stacks import ring_and_transient_stacks

    ring, transient = ring_and_transient_stacks(open_dataset(argument, radius=4.5), np.arange(4.0), 1.0,
                                                device=choose_device("cuda"))
    np.savez(out, ring=ring.images, transient=transient.images, counts=ring.counts)


def simulator_volume():
    """``(volume, tables, majorant, lit, streams)`` of the simulator's kernel cases: a 6 x 5 x 5
    volume with a block of a second material, two channels that scatter alike (mus 1 and 2, g 0.8
    and 0.3), three lit points on streams 3, 7 and 11."""
    from ringlight.core.simulate.tables import walk_tables

    tables, majorant = walk_tables(np.array([1.0, 2.0]), np.array([[0.01, 0.1], [0.02, 0.05]]), np.array([0.8, 0.3]))
    volume = np.zeros((6, 5, 5), np.uint8)
    volume[2:4, 1:3, 2:4] = 1
    return volume, tables, majorant, np.array([[1, 1], [2, 3], [4, 0]], np.int64), np.array([3, 7, 11])


def simulate_points(out: Path, argument: str) -> None:
    """The simulator's points kernel on :func:`simulator_volume`, 20 photons per point of seed 9 (bins of 4),
    projector and camera oblique: the camera measure (``camera_*``) and the exitance
    (``exitance_*``)."""
    from ringlight.core.simulate.camera import optics
    from ringlight.core.simulate.photon_cuda import simulate_points_cuda

    volume, tables, majorant, lit, streams = simulator_volume()
    arrays = {}
    for measure in ("camera", "exitance"):
        windows, truth = np.zeros((3, 5, 5, 2)), np.zeros((1, 8, 5, 5, 2))
        simulate_points_cuda(volume, tables, majorant, optics(1.4, 6.0, (20.0, 30.0), (25.0, 10.0)),
                             np.zeros((0, 0, 0, 0)), measure == "camera", lit, 20, 9, streams, 4.0, windows, truth)
        arrays[f"{measure}_windows"], arrays[f"{measure}_truth"] = windows, truth[0]
    np.savez(out, **arrays)


def simulate_differences(out: Path, argument: str) -> None:
    """The simulator's correlated differences (:func:`.reference.simulate_point_differences`) on
    :func:`simulator_volume` against its layered reference, camera straight down, 5 photons for
    points 0 and 2, point 1 scored whole (direct), seed 4."""
    from ringlight.core.device import choose_device

    windows, truth = np.zeros((3, 5, 5, 2)), np.zeros((1, 8, 5, 5, 2))
    touches = run_differences(windows, truth, choose_device("cuda"))
    np.savez(out, windows=windows, truth=truth[0], touches=touches)


def run_differences(windows, truth, device=None):
    """:func:`simulate_differences`' run on ``device`` (the CPU when None) into ``windows``
    (3, 5, 5, 2) and ``truth`` (blocks, 8, 5, 5, 2); returns the touches."""
    from ringlight.core.simulate.camera import optics
    from ringlight.core.simulate.reference import mixed_voxels, reference_optics, reference_volume, \
        simulate_point_differences

    volume, tables, majorant, lit, streams = simulator_volume()
    base = reference_volume(volume)
    return simulate_point_differences(
        volume, base, mixed_voxels(volume, base, 1.4, (0.0, 0.0)), tables, majorant, optics(1.4, 6.0),
        reference_optics(1.4, 6.0, (0.0, 0.0), (0.0, 0.0), base), True, (0.0, 0.0), lit, [5, 5, 5],
        [False, True, False], 4, streams, 1.0, windows, truth, device)


def mcml_slab(out: Path, argument: str) -> None:
    """The exitance of MCML's slab (mu_a 10, mu_s 90 per grid step, g 0.75, n 1, 0.02 deep) by the
    points kernel: 1024 photons on 16 streams of seed 7, each photon's window total."""
    from ringlight.core.simulate.camera import optics
    from ringlight.core.simulate.photon_cuda import simulate_points_cuda
    from ringlight.core.simulate.tables import single_channel_tables

    tables, majorant = single_channel_tables([100.0], [0.9], [0.75])
    windows, truth = np.zeros((16, 3, 3, 1)), np.zeros((1, 0, 1, 1, 1))
    simulate_points_cuda(np.zeros((1, 1, 1), np.uint8), tables, majorant, optics(1.0, 0.02),
                         np.zeros((0, 0, 0, 0)), False, np.zeros((16, 2), np.int64), 64, 7, np.arange(16), 1.0,
                         windows, truth)
    np.savez(out, windows=windows)


def simulate_command(out: Path, argument: str) -> None:
    """``ringlight simulate homogeneous --size 3x3 --photons 4 --device cuda --out ARGUMENT``: its
    output and the notes it wrote."""
    import contextlib
    import io

    from ringlight.app.main import main
    from ringlight.core import read_manifest

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        status = main(["simulate", "homogeneous", "--size", "3x3", "--photons", "4", "--device", "cuda",
                       "--out", argument])
    np.savez(out, status=status, printed=printed.getvalue(), notes=read_manifest(argument).notes)


def device(out: Path, argument: str) -> None:
    from ringlight.core.device import choose_device

    np.savez(out, name=choose_device("cuda").name, auto=choose_device("auto").kind)


CASES = {"radial": radial, "white": white, "stacks": stacks, "device": device, "simulate_points": simulate_points,
         "simulate_differences": simulate_differences, "mcml_slab": mcml_slab, "simulate_command": simulate_command,
         "cells": cells}


def run_cases(cases: dict[str, str], folder: Path) -> dict[str, dict[str, np.ndarray] | str] | None:
    """Run each of ``cases`` (name: argument) on a GPU of this process, or all in one child process
    in the simulator, saving FOLDER/CASE.npz; each case's arrays, or the traceback of a case that
    failed (the others still run), or None when neither a GPU nor the simulator is there."""
    from ringlight.core.device import cuda_device

    if cuda_device() is not None:
        for case, argument in cases.items():
            _run_one(case, folder, argument)
    else:
        env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
        done = subprocess.run([sys.executable, __file__, str(folder), *(f"{case}={argument}" for case, argument
                                                                       in cases.items())],
                              env=env, capture_output=True, text=True, timeout=600)
        if done.returncode == UNAVAILABLE:
            return None
        assert done.returncode == 0, done.stderr[-3000:]
    runs = {}
    for case in cases:
        failed = folder / f"{case}.failed"
        if failed.exists():
            runs[case] = failed.read_text()
            continue
        with np.load(folder / f"{case}.npz") as arrays:
            runs[case] = dict(arrays)
    return runs


def _run_one(case: str, folder: Path, argument: str) -> None:
    """Run ``case`` into FOLDER/CASE.npz, or write its traceback to FOLDER/CASE.failed."""
    try:
        CASES[case](folder / f"{case}.npz", argument)
    except Exception:
        (folder / f"{case}.failed").write_text(traceback.format_exc())


POLL_S = 0.001
"""How long the simulator's block manager waits on a thread per poll, seconds."""


def _wait_instead_of_spinning() -> None:
    """Make the simulator's block manager wait for its threads rather than spin: it polls each
    thread's ``is_alive`` in a loop that holds the GIL, which took up to half of a case's CPU time
    (the radial case: 6.9 CPU-s, 3.8 with this). Results are the same: the loop still sees every
    thread end or block in ``syncthreads`` (which the kernels here never call), up to POLL_S later."""
    import threading

    try:
        from numba.cuda.simulator.kernel import BlockThread
    except ImportError:  # another simulator layout: poll as it does
        return

    def is_alive(thread) -> bool:
        thread.join(POLL_S)
        return threading.Thread.is_alive(thread)

    BlockThread.is_alive = is_alive


if __name__ == "__main__":
    try:
        import numba.cuda  # the simulator (numba's own, or numba-cuda's) must import
    except ImportError:
        sys.exit(UNAVAILABLE)
    assert numba.cuda.is_available()  # True in the simulator
    # The simulator adds the generator's uint64 words as numpy scalars, whose wrap-around (intended:
    # arithmetic modulo 2^64, as on the device) numpy reports as an overflow.
    warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning)
    _wait_instead_of_spinning()
    for pair in sys.argv[2:]:
        name, _, value = pair.partition("=")
        _run_one(name, Path(sys.argv[1]), value)
