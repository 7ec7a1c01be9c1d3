"""Benchmark of paper-scale datasets (not a test: prints figures measured in one run).

For each size it writes a synthetic parallel dataset with the project's writer (lit points on a
lattice of spacing 2R + 1, so (2R + 1)^2 frames; each impulse a smooth coloured fall-off within
R), then prints, each measured in a fresh process so that peak RSS is the open's own:

- first open (empty store) against the time to merely decode every frame on all cores (a frame
  a thread, each checked and decoded as an open reads it);
- reopen time;
- peak RSS of the first open and of a 21-radius transient stack, against the memory budget;
- store size against the EXR frames' size;
- the transient stack's time, local and on a LocalCluster of two worker processes;
- the explorer's open with its default stacks, their ring coverage and noise estimate, as its
  workers run them, twice: first computing the stacks and noise (and saving them in a user cache
  made for the run), then again reading them back.

    python benchmarks/bench_scale.py [--sizes 256,512,800] [--with-1024] [--folder DIR] [--keep]
                                     [--repeat N]

Sizes use R = 24; ``--with-1024`` adds 1024 px at R = 32 (about 40 GB of responses, 20 GB of
store and an hour). The datasets are written under ``--folder`` (default: a temporary folder,
removed afterwards unless ``--keep``); a dataset already there is reused. Timings on a shared
2-core machine move by up to a factor of 2 from run to run: ``--repeat N`` measures the decode
and the first open N times each, taking turns, and prints their median and range.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RADII = 21
"""Radii of the transient stack: 0 .. 20, dr 1."""


def write_synthetic(folder: Path, size: int, radius: int) -> None:
    """A parallel dataset of ``size`` x ``size`` points at ``max_radius`` = ``radius``."""
    from ringlight.core.dataset.writer import DatasetWriter

    spacing = 2 * radius + 1
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    distance = np.hypot(yy, xx)
    kernel = (np.exp(-distance / 6.0)[..., None] * np.array([0.9, 0.6, 0.3])).astype(np.float32)
    kernel[distance > radius] = 0.0
    with DatasetWriter(folder, (size, size), max_radius=float(radius), half=True) as writer:
        for oy in range(spacing):
            for ox in range(spacing):
                image = np.zeros((size + 2 * radius, size + 2 * radius, 3), np.float32)
                lit = [(y, x) for y in range(oy, size, spacing) for x in range(ox, size, spacing)]
                for y, x in lit:
                    image[y:y + spacing, x:x + spacing] += kernel * (1.0 + 0.2 * np.sin(0.05 * (y + 2 * x)))
                writer.add_frame(image[radius:radius + size, radius:radius + size], lit=[list(p) for p in lit])


def worker(task: str, folder: str) -> None:
    """Run one measured step in this (fresh) process and print its figures as JSON."""
    from ringlight.core import open_dataset, transient_stack
    from ringlight.core.dataset.exr import read_exr_channels
    from ringlight.core.dataset.manifest import read_manifest
    from ringlight.core.dataset.memory import memory_budget

    from ringlight.core.colourspaces import colour_module

    colour_module()  # the library's own import (seconds, once per process) is not the dataset's
    figures = {"budget": memory_budget()}
    start = time.perf_counter()
    if task == "decode":
        from concurrent.futures import ThreadPoolExecutor

        import OpenEXR

        # The fastest all-core decode measured: a frame a thread, the library's own threads off
        # (256 px: 1.5 s; one frame at a time on the library's threads 2.8-3.5 s).
        OpenEXR.set_global_thread_count(0)
        manifest = read_manifest(folder)
        shape = (manifest.height, manifest.width)
        with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
            for _ in pool.map(lambda frame: read_exr_channels(manifest.folder / frame.file, ("R", "G", "B"), shape),
                              manifest.frames):
                pass  # each frame dropped as it arrives
    elif task == "open":
        dataset = open_dataset(folder)
        figures["in_memory"] = dataset.in_memory
    elif task == "view":
        from ringlight.app.session import load_for_viewing
        from ringlight.core.rings.stack_cache import cached_noise

        loaded = load_for_viewing(folder, None, lambda fraction: None)
        cached_noise(loaded.dataset, loaded.stacks.pair.request)
    elif task in ("stack", "cluster"):
        dataset = open_dataset(folder)
        start = time.perf_counter()
        if task == "stack":
            transient_stack(dataset, np.arange(RADII, dtype=float), 1.0)
        else:
            from dask.distributed import Client, LocalCluster

            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                    Client(cluster) as client:
                client.run(lambda: None)  # workers up before the clock
                start = time.perf_counter()
                transient_stack(dataset, np.arange(RADII, dtype=float), 1.0, scheduler=client)
    figures["seconds"] = time.perf_counter() - start
    figures["peak_rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps(figures))


def measured(task: str, folder: Path, env: dict | None = None) -> dict:
    result = subprocess.run([sys.executable, __file__, "--worker", task, str(folder)], capture_output=True,
                            text=True, check=False, env=None if env is None else {**os.environ, **env})
    if result.returncode:
        raise SystemExit(f"{task} on {folder} failed:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def gib(count: float) -> str:
    return f"{count / 2**30:.2f} GiB"


def spread(values: list[float]) -> str:
    """``median`` s, with ``(min-max)`` when measured more than once."""
    text = f"{float(np.median(values)):.1f} s"
    return text if len(values) == 1 else f"{text} ({min(values):.1f}-{max(values):.1f}, {len(values)} runs)"


def bench(root: Path, size: int, radius: int, repeat: int = 1) -> None:
    folder = root / f"scale-{size}-r{radius}"
    if not (folder / "dataset.json").exists():
        start = time.perf_counter()
        write_synthetic(folder, size, radius)
        print(f"{size} px, R {radius}: wrote {(2 * radius + 1) ** 2} frames in {time.perf_counter() - start:.0f} s",
              flush=True)
    shutil.rmtree(folder / ".ringlight-cache", ignore_errors=True)
    from ringlight.core.dataset.response_store import entry_bytes

    exr = entry_bytes(folder / "frames")
    decodes, opens = [], []
    for run in range(repeat):  # taking turns, so that a slow spell of the machine hits both
        if run:
            shutil.rmtree(folder / ".ringlight-cache", ignore_errors=True)
        decodes.append(measured("decode", folder)["seconds"])
        first = measured("open", folder)
        opens.append(first["seconds"])
    store = entry_bytes(folder / ".ringlight-cache")
    reopen = measured("open", folder)
    stack = measured("stack", folder)
    cluster = measured("cluster", folder)
    with tempfile.TemporaryDirectory(prefix="ringlight-view-cache-") as user_cache:
        view_first = measured("view", folder, {"RINGLIGHT_CACHE_DIR": user_cache})
        view_again = measured("view", folder, {"RINGLIGHT_CACHE_DIR": user_cache})
    from ringlight.core.dataset.disc import disc_offset_count

    responses = size * size * disc_offset_count(radius) * 12
    budget = first["budget"]
    print(f"{size} px, R {radius}: responses {gib(responses)}, budget {gib(budget)}, "
          f"{'in memory' if first['in_memory'] else 'out of core'}", flush=True)
    print(f"  first open   {spread(opens)}; decode of every frame on all cores {spread(decodes)} "
          f"(ratio of medians {np.median(opens) / np.median(decodes):.2f}, target <= 1.5)")
    print(f"  reopen       {reopen['seconds']:7.2f} s (target <= 2)")
    print(f"  peak RSS     open {gib(first['peak_rss'])}, stack {gib(stack['peak_rss'])} "
          f"(budget {gib(budget)}; target 4 GiB at 800 px, 6 GiB at 1024 px)")
    print(f"  store        {gib(store)} beside {gib(exr)} of EXR frames (ratio {store / exr:.2f}, target <= 1.2)")
    print(f"  stack        {RADII} transient radii: local {stack['seconds']:.1f} s, LocalCluster of 2 processes "
          f"{cluster['seconds']:.1f} s")
    print(f"  explorer     open with its stacks, coverage and noise: {view_first['seconds']:.1f} s computed, "
          f"{view_again['seconds']:.1f} s read back (peak RSS {gib(view_first['peak_rss'])}, "
          f"{gib(view_again['peak_rss'])})", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="256,512,800", help="grid sizes at R 24 (comma-separated)")
    parser.add_argument("--with-1024", action="store_true", help="also 1024 px at R 32 (40 GB of responses)")
    parser.add_argument("--folder", help="where the datasets are written (kept)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary datasets")
    parser.add_argument("--repeat", type=int, default=1,
                        help="measure the decode and the first open this many times each (median and range)")
    parser.add_argument("--worker", nargs=2, metavar=("TASK", "FOLDER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    root = Path(args.folder) if args.folder else Path(tempfile.mkdtemp(prefix="ringlight-scale-"))
    root.mkdir(parents=True, exist_ok=True)
    try:
        for size in (int(text) for text in args.sizes.split(",") if text):
            bench(root, size, 24, args.repeat)
        if args.with_1024:
            bench(root, 1024, 32, args.repeat)
    finally:
        if not args.folder and not args.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
