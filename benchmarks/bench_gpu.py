"""Benchmark of the CUDA kernels against the CPU kernels (not a test), measured in one run:

(1) White runs, photons per second on every CPU core and on the GPU (100 times the photons),
    after a warm-up compile of each, and their ratio: the optics table's (a half-space of
    n = 1.4, g = 0.8 in mean free paths, :mod:`ringlight.core.optics.radial`) and the layer
    inversion's (the layers3 sample's search slab: 9 depth bins of mus 1 per grid step, 64 grid
    steps deep, g 0, n 1.4, :mod:`ringlight.core.inversion.white_mc`).
(2) The simulator (``ringlight simulate``'s walk, :mod:`ringlight.core.simulate.photon`): photons
    per second on the CPU and the GPU for MCML's slab (manual Table 6.1: mu_a 1, mu_s 9 per grid
    step (of 1 mm), g 0.75, n 1, 0.2 grid steps deep; one lit point, the camera measure and the exitance)
    and for the red-bead sample (:func:`ringlight.core.simulate.transport.simulate_transport`, the
    reference estimator, the whole grid). With ``pmcx`` installed, MCX on the same GPU for the same
    slab: MCX scores fluence and exitance, not a next-event estimate at every scattering, so the like
    for like figure is ringlight's exitance measure; the camera measure is the one ``simulate`` runs.
    Then the bundled red-bead sample as it was made (48 x 48, its photons per lit point, the reference
    estimator) on the GPU alone: its seconds against the CPU's recorded in the sample, and the RMS
    difference of the two runs' responses, relative (both are samples of the same expectation).
(3) The layer inversion's white run tallied in cells (:mod:`ringlight.core.inversion.white_cells`)
    for layers3's known structure (boundaries 2, 5), as ``layers --method inverse`` runs its
    final fits: seconds and photons per second on the CPU and the GPU (10 times the photons).
(4) The ring sums of a transient stack of radii 0..R-1 (rings 0..R, ``--radii R``) on a random
    800 x 800 dataset (offsets within radius R + 0.5): seconds on the CPU, on the GPU with the
    responses' transfer and the images' return, and on the GPU with the responses already there
    (the kernel alone), and their ratios.

Without a usable GPU (``ringlight[cuda]`` and an NVIDIA driver) the GPU part is skipped with a
line saying so; the CPU figures are still printed.

    python benchmarks/bench_gpu.py [--photons 20000] [--size 800] [--radii 11] [--bead-photons 20]
                                   [--cells-photons 100000]

The CPU runs on numba's threads: ``NUMBA_NUM_THREADS=2`` makes it the 2-core CPU the targets name.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from ringlight.core.device import cpu_device, cuda_device
from ringlight.core.inversion.forward import Structure
from ringlight.core.inversion.search import REACH, database_optics
from ringlight.core.inversion.settings import InversionSettings
from ringlight.core.inversion.white_cells import run_cells
from ringlight.core.inversion.white_mc import SlabOptics, run_white
from ringlight.core.optics.radial import run_radial
from ringlight.core.rings.stacks import _ring_sums, _ring_tables
from ringlight.core.rings.members import ring_members, unit_weight_rings
from ringlight.core.simulate.camera import optics
from ringlight.core.simulate.photon import point_kernels
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.samples import load_sample
from ringlight.core.simulate.tables import single_channel_tables
from ringlight.core.simulate.transport import simulate_transport


SLAB = SlabOptics((1.0,) * 9, 0.0, 1.4, 64.0, REACH)


def radial_rate(photons: int, device) -> float:
    """Photons per second of the optics table's white run on ``device`` (after one small run)."""
    run_radial(1.4, 0.8, 1000, seed=1, device=device)
    start = time.perf_counter()
    run = run_radial(1.4, 0.8, photons, seed=2, device=device)
    return run.photons / (time.perf_counter() - start)


def slab_rate(photons: int, device) -> float:
    """Photons per second of the layer inversion's white run (records) on ``device``."""
    run_white(SLAB, 64, seed=1, device=device)
    start = time.perf_counter()
    run = run_white(SLAB, photons, seed=2, device=device)
    return run.photons / (time.perf_counter() - start)


MCML_SLAB = {"mua": 1.0, "mus": 9.0, "g": 0.75, "n": 1.0, "depth": 0.2}
"""MCML manual Table 6.1's slab (10 and 90 per cm, 0.02 cm) in grid steps of 1 mm."""


def slab_simulator_rate(photons: int, device, camera: bool) -> float:
    """Photons per second of the simulator's walk in MCML's slab, one lit point, on ``device``
    (the photons shared among 64 streams on the CPU, 16384 on a GPU; after a warm-up run)."""
    slab = MCML_SLAB
    mu_t = slab["mua"] + slab["mus"]
    tables, majorant = single_channel_tables([mu_t], [slab["mus"] / mu_t], [slab["g"]])
    geometry = optics(slab["n"], slab["depth"])
    streams = 1 << 14 if device.is_cuda else 64
    simulate_points = point_kernels(device)[0]

    def run(count, seed):
        per_stream = max(1, count // streams)
        windows = np.zeros((streams, 3, 3, 1))
        simulate_points(np.zeros((1, 1, 1), np.uint8), tables, majorant, geometry, np.zeros((0, 0, 0, 0)), camera,
                        np.zeros((streams, 2), np.int64), per_stream, seed, np.arange(streams), 1.0, windows,
                        np.zeros((min(16, streams), 0, 1, 1, 1)))
        return per_stream * streams

    run(streams, 1)
    start = time.perf_counter()
    traced = run(photons, 2)
    return traced / (time.perf_counter() - start)


def bead_rate(photons: int, device) -> tuple[float, float]:
    """``(photons per second, seconds)`` of the red-bead sample (40 x 40, ``photons`` per lit point
    and channel, counted as ``simulate`` counts them) on ``device``, after a warm-up run on a
    6 x 6 grid. Each run has fixed costs (the allocation's pilot, spreading the kernel): few
    photons understate the rate."""
    simulate_transport(load_scene("red-bead", size=(6, 6)), photons=1, seed=1, device=device)
    scene = load_scene("red-bead")
    run = simulate_transport(scene, photons=photons, seed=2, device=device)
    return scene.height * scene.width * photons * (1 if scene.grey else 3) / run.seconds, run.seconds


def bundled_bead(device) -> str:
    """The bundled red-bead sample's run again on ``device`` (its scene, photons, seed and
    estimator): a line with its seconds against the CPU's recorded in the sample and the relative
    RMS difference of the two runs' responses."""
    bundled, _ = load_sample("red-bead")
    scene = bundled.scene
    run = simulate_transport(scene, photons=bundled.photons, seed=bundled.seed + 1, estimator=bundled.estimator,
                             device=device)
    difference = np.sqrt(np.mean((run.windows - bundled.windows) ** 2) / np.mean(bundled.windows ** 2))
    return (f"red-bead as bundled ({scene.height} x {scene.width}, {bundled.photons} photons per lit point, "
            f"{bundled.estimator}): GPU {run.seconds:.1f} s (target 60 s), the sample's CPU run {bundled.seconds:.0f} s; "
            f"responses differ from the bundled run's by {difference:.4f} RMS, relative")


LAYERS3_KNOWN = InversionSettings(3, (2, 5), (0.5, 0.5, 1.5), 1.3, 0.0, 24.0)
"""The known structure of :mod:`bench_inversion`'s fit on layers3."""


def cells_seconds(photons: int, device) -> float:
    """Seconds of a white run of ``photons`` tallied in cells for :data:`LAYERS3_KNOWN`, on ``device``
    (after a small run that compiles)."""
    optics = database_optics(LAYERS3_KNOWN, LAYERS3_KNOWN.mus)
    structure = Structure((0, *LAYERS3_KNOWN.boundaries))
    run_cells(optics, structure, 1000, seed=1, device=device)
    start = time.perf_counter()
    run_cells(optics, structure, photons, seed=2, device=device)
    return time.perf_counter() - start


def mcx_rate(photons: int) -> str:
    """MCX (``pmcx``) in MCML's slab on the GPU: its photons per second as it reports them, or a
    plain line saying why there is none."""
    try:
        import pmcx
    except ImportError:
        return "MCX: pmcx not installed (pip install pmcx): skipped"
    slab = MCML_SLAB
    config = {"nphoton": photons, "vol": np.ones((200, 200, 2), np.uint8), "unitinmm": 0.1,
              "prop": [[0, 0, 1, 1], [slab["mua"], slab["mus"], slab["g"], slab["n"]]],
              "srcpos": [100, 100, 0], "srcdir": [0, 0, 1], "issrcfrom0": 1, "tstart": 0, "tend": 5e-9,
              "tstep": 5e-9, "isreflect": 0, "issaveref": 1}
    try:
        result = pmcx.run(config)
        seconds = float(result["stat"]["runtime"]) / 1000.0
    except Exception as error:  # pmcx reports a missing GPU or driver in many ways
        return f"MCX: pmcx could not run ({error}): skipped"
    return f"MCX (pmcx), same slab, exitance and fluence: {photons / seconds / 1e6:.4f} M photons/s"


class _Dataset:
    """What :func:`_ring_tables` reads of a dataset: offsets and max_radius."""

    def __init__(self, offsets, max_radius):
        self.offsets = offsets
        self.max_radius = max_radius


def stack_arguments(size: int, radii: int) -> tuple:
    """The ring sums' arguments for rings of radii 0..``radii`` (those of a transient stack of radii
    0..``radii`` - 1) on a random dataset of ``size`` x ``size`` points (responses of
    ``size^2 x K x 12`` bytes, K the offsets within ``radii + 0.5``: 3.2 GB at 800 and 11 rings)."""
    reach = radii + 0.5
    grid = np.arange(-radii - 1, radii + 2)
    dy, dx = np.meshgrid(grid, grid, indexing="ij")
    inside = dy**2 + dx**2 <= reach**2
    order = np.argsort(np.hypot(dy[inside], dx[inside]), kind="stable")
    offsets = np.stack([dy[inside][order], dx[inside][order]], 1).astype(np.int64)
    tables = _ring_tables(_Dataset(offsets, reach), np.arange(radii + 1.0), 1.0, False)
    responses = np.random.default_rng(0).random((size, size, len(offsets), 3), dtype=np.float32)
    lit = np.ones((size, size), bool)
    counts, totals = ring_members(lit, lit, offsets, tables, unit_weight_rings(tables), 0, size)
    images = np.empty((len(tables[0]), size, size, 3), np.float32)
    return (responses, *tables, unit_weight_rings(tables), counts, totals, images)


def call_seconds(call, *arguments) -> float:
    """Seconds of ``call(*arguments)``, after one warm-up call."""
    call(*arguments)
    start = time.perf_counter()
    call(*arguments)
    return time.perf_counter() - start


def resident_seconds(arguments) -> float:
    """Seconds of the GPU's ring sums with the responses and images already on the device."""
    from numba import cuda

    from ringlight.core.rings.stack_cuda import device_ring_sums

    responses, first, stop, weight_start, weights, _, counts, totals, images = arguments
    on_device = (cuda.to_device(responses), first, stop, weight_start, weights, counts, totals,
                 cuda.device_array(images.shape, np.float32))

    def run(*arguments):
        device_ring_sums(*arguments)
        cuda.synchronize()

    return call_seconds(run, *on_device)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=20_000)
    parser.add_argument("--size", type=int, default=800)
    parser.add_argument("--radii", type=int, default=11, help="the transient stack's radii (0..R-1)")
    parser.add_argument("--bead-photons", type=int, default=20,
                        help="photons per lit point of the red-bead run on the CPU (100x on the GPU)")
    parser.add_argument("--cells-photons", type=int, default=100_000,
                        help="photons of the white run in cells on the CPU (10x on the GPU)")
    args = parser.parse_args()
    cpu, gpu = cpu_device(), cuda_device()
    if gpu is not None and gpu.name == "CUDA simulator":
        gpu = None  # the simulator runs kernels in Python: nothing to time
    print(f"CPU: {cpu.name}; GPU: {gpu.name if gpu else 'none usable: the GPU figures are skipped'}")
    for name, rate in (("optics table's white run (half-space, n 1.4, g 0.8)", radial_rate),
                       ("layer inversion's white run (9 bins, 64 deep, n 1.4)", slab_rate)):
        cpu_rate = rate(args.photons, cpu)
        print(f"{name}: CPU {cpu_rate / 1e6:.4f} M photons/s", end="")
        if gpu is not None:
            gpu_rate = rate(args.photons * 100, gpu)
            print(f", GPU {gpu_rate / 1e6:.4f} M photons/s: {gpu_rate / cpu_rate:.1f}x", end="")
        print()
    for measure, camera in (("camera measure", True), ("exitance", False)):
        cpu_rate = slab_simulator_rate(args.photons * 10, cpu, camera)
        print(f"simulator, MCML slab, {measure}: CPU {cpu_rate / 1e6:.4f} M photons/s", end="")
        if gpu is not None:
            gpu_rate = slab_simulator_rate(args.photons * 1000, gpu, camera)
            print(f", GPU {gpu_rate / 1e6:.4f} M photons/s: {gpu_rate / cpu_rate:.1f}x", end="")
        print()
    print(mcx_rate(args.photons * 1000) if gpu is not None else "MCX: no usable GPU: skipped")
    cpu_rate, cpu_seconds = bead_rate(args.bead_photons, cpu)
    print(f"simulator, red-bead sample: CPU {cpu_rate / 1e6:.4f} M photons/s ({cpu_seconds:.1f} s)", end="")
    if gpu is not None:
        gpu_rate, gpu_seconds = bead_rate(args.bead_photons * 100, gpu)
        print(f", GPU {gpu_rate / 1e6:.4f} M photons/s ({gpu_seconds:.1f} s): {gpu_rate / cpu_rate:.1f}x", end="")
    print()
    if gpu is not None:
        print(bundled_bead(gpu))
    cpu_seconds = cells_seconds(args.cells_photons, cpu)
    print(f"white run in cells, layers3's known structure: CPU {args.cells_photons / cpu_seconds / 1e6:.4f} M photons/s "
          f"({cpu_seconds:.1f} s)", end="")
    if gpu is not None:
        gpu_seconds = cells_seconds(args.cells_photons * 10, gpu)
        print(f", GPU {args.cells_photons * 10 / gpu_seconds / 1e6:.4f} M photons/s ({gpu_seconds:.1f} s): "
              f"{cpu_seconds * 10 / gpu_seconds:.1f}x", end="")
    print()
    arguments = stack_arguments(args.size, args.radii)
    cpu_seconds = call_seconds(_ring_sums, *arguments)
    print(f"ring sums, {args.size} x {args.size} points, {args.radii + 1} rings, {arguments[0].nbytes / 1e9:.1f} GB: "
          f"CPU {cpu_seconds:.3f} s", end="")
    if gpu is not None:
        from ringlight.core.rings.stack_cuda import cuda_ring_sums

        gpu_seconds = call_seconds(cuda_ring_sums, *arguments)
        resident = resident_seconds(arguments)
        print(f", GPU {gpu_seconds:.3f} s with transfers ({cpu_seconds / gpu_seconds:.1f}x), {resident:.4f} s with "
              f"the responses on the GPU ({cpu_seconds / resident:.1f}x)", end="")
    print()


if __name__ == "__main__":
    main()
