"""Benchmark of manifest parsing and validation (not a test: prints figures from one run).

Writes a one-point-per-frame manifest of ``--frames`` frames (default 100,000, on a 250 x 400
grid) and a multiplexed one of the same number of lit points (groups on a lattice, max_radius 2),
then times ``read_manifest`` (reading, bounded JSON decoding, validation; best of 3) and
measures its peak Python memory (tracemalloc, separate run). Issue 11 measured 51 s for 100,000
frames before this work; the target is at least 10 times faster, so at most 5.1 s. Printed: the
time, the target and their ratio (over 1 means faster than the target).

With ``--pipeline``, it times instead the work per frame after the parse (issue 40, case 12: "the
per-frame work after parsing must be as cheap as the parse"): a dataset of ``--frames`` one-point
frames on a 10 x 10 grid (max_radius 3), each frame a hard link to one of 50 small EXR files, then
the parse (``read_manifest``), the check of every file's header (``find_file_problems``, what
``ringlight info`` does), the plan of the open (``plan_open``: with no store of this manifest, no
file is stat'ed), the key a reopen makes (``cache.stat_key``: a stat a file) and the open itself
(``open_dataset`` without the cache: every frame located, read, checked, decoded and scattered),
each per frame in CPU time of the whole process (all threads; user + system: the system part is
the kernel's, mostly the four calls that open, stat, read and close each file) and in wall time,
each as a ratio to the parse's. What a process pays once (imports, compiled kernels loaded: about
0.4-0.5 s) is paid first by the check and open of a 1000-frame dataset, printed apart: counted in
the steps, it made 1-2 us of a 100 000-frame check's "per frame". With ``--pieces``, the open's
pieces are timed after it, on one thread, in runs of 1024 frames (:func:`open_pieces`): the reads
alone, the reads with the decode, and the scatter.

Measured on the 2-core development machine (shared with other work), 100 000 frames, four runs of
the code before the last change (stop 46) alternated with four after it, load average 3.8-7.6, us of
CPU a frame before and after: parse 5.8-8.7 and 5.3-6.5; check 6.5-7.7 and 5.5-5.9; open 11.7-13.2
(user 6.4-8.2, system 5.0-5.5; 1.5-2.0x the parse) and 9.7-11.2 (user 4.5-5.4, system 5.0-5.8;
1.5-2.1x). The system part, the kernel's four calls a file, is by itself about the parse's cost. The
pieces after it (two runs, load 4-5): reads 5.9-6.5 (user 0.5-0.8, system 5.3-5.7), reads and decode
9.4-10.1, scatter 0.1-0.2. At stop 46 (load 2-5): parse 6.1-7.3, check 6.6-7.4, open 11.7-13.1.
Before issue 40's work, on the same dataset: ``ringlight info`` 10.3 s of CPU, a first ``ringlight
stack`` 31.8 s.

With ``--hostile``, it times instead the raw JSON values the fuzz tests
(``tests/test_fuzz_input.py``) plant in manifests (deep nesting, 5000-digit numbers, NaN, lone
surrogates), each in every field of a small manifest: the slowest case, which the tests no longer
time (issue 39: wall times fail on a loaded machine; the tests bound memory instead).

    python benchmarks/bench_manifest.py [--frames 100000] [--hostile | --pipeline [--pieces]]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
import tracemalloc
from pathlib import Path

from ringlight.core import RinglightError
from ringlight.core.dataset.manifest import read_manifest

BEFORE_S = 51.0
"""Seconds the issue measured for 100,000 frames before the fix."""
TARGET_S = BEFORE_S / 10


def write_manifest(folder: Path, frames: int, multiplexed: bool) -> int:
    """Write the manifest; returns its size in bytes."""
    width = 400
    height = -(-frames // width)
    if multiplexed:  # 5-step lattice: points 5 apart, more than 2 * max_radius = 4
        groups = [[[y, x] for y in range(phase_y, height, 5) for x in range(phase_x, width, 5)]
                  for phase_y in range(5) for phase_x in range(5)]
    else:
        groups = [[[i // width, i % width]] for i in range(frames)]
    document = {"format": "ringlight-impulse", "version": 1, "grid": {"height": height, "width": width},
                "frames": [{"file": f"frames/{i:06d}.exr", "lit": lit, "exposure": 1.0}
                           for i, lit in enumerate(groups)]}
    if multiplexed:
        document["max_radius"] = 2
    text = json.dumps(document)
    (folder / "dataset.json").write_text(text)
    return len(text)


HOSTILE_RAW = [
    "NaN", "Infinity", "-Infinity", "1e999", "-1e999", "1e-320", "4.9e-324", "1e39", "-0.0",
    "9" * 31, "9" * 401, "9" * 5000, "-" + "9" * 40, "[" * 5000 + "]" * 5000,
    '{"a":' * 3000 + "1" + "}" * 3000, '"\\ud800"', '"\\udc80x"', '"a\\u0000b"',
]
"""The raw JSON values of the fuzz tests' ``hostile_raw``."""
HOSTILE_FIELDS = ['"version": 1', '"height": 4', '"width": 3', '"exposure": 1.0', '"lit": [[0, 0]]',
                  '"file": "frames/00000.exr"']
"""Fields of the small manifest each raw value replaces the value of."""


def time_hostile() -> None:
    """Print the time of ``read_manifest`` on every hostile value in every field (best of 3)."""
    frames = [{"file": f"frames/{i:05d}.exr", "lit": [[i // 3, i % 3]], "exposure": 1.0} for i in range(12)]
    text = json.dumps({"format": "ringlight-impulse", "version": 1, "grid": {"height": 4, "width": 3},
                       "frames": frames})
    cases = []
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        for field in HOSTILE_FIELDS:
            for raw in HOSTILE_RAW:
                (folder / "dataset.json").write_text(text.replace(field, field.split(":")[0] + ": " + raw, 1))
                times = []
                for _ in range(3):
                    started = time.perf_counter()
                    try:
                        read_manifest(folder)
                        outcome = "read"
                    except RinglightError:
                        outcome = "refused"
                    times.append(time.perf_counter() - started)
                cases.append((min(times), field.split(":")[0], raw[:24], outcome))
    cases.sort(reverse=True)
    print(f"{len(cases)} hostile manifests; slowest {cases[0][0] * 1000:.1f} ms, median "
          f"{cases[len(cases) // 2][0] * 1000:.2f} ms")
    for seconds, field, raw, outcome in cases[:5]:
        print(f"  {seconds * 1000:8.2f} ms  {field} = {raw!r} ({outcome})")


def write_linked_dataset(folder: Path, frames: int, files: int = 50) -> None:
    """A one-point-per-frame dataset on a 10 x 10 grid whose frames are hard links to ``files``
    small EXR files (one file system entry each, few bytes on disk)."""
    import os

    import numpy as np
    from ringlight.core.dataset.exr import write_exr_rgb

    (folder / "frames").mkdir(parents=True)
    for index in range(files):
        write_exr_rgb(folder / "frames" / f"base{index}.exr", np.full((10, 10, 3), 0.01 * (index + 1), np.float32),
                      half=True)
    entries = []
    for index in range(frames):
        name = f"frames/{index:07d}.exr"
        os.link(folder / "frames" / f"base{index % files}.exr", folder / name)
        entries.append({"file": name, "lit": [[(index // 10) % 10, index % 10]], "exposure": 1.0})
    (folder / "dataset.json").write_text(json.dumps({"format": "ringlight-impulse", "version": 1, "max_radius": 3,
                                                     "grid": {"height": 10, "width": 10}, "frames": entries}))


def measured(steps: dict, step: str, work):
    """``work()``, its user and system CPU (all threads) and wall seconds kept as ``steps[step]``."""
    started, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    result = work()
    wall, ended = time.perf_counter() - wall, resource.getrusage(resource.RUSAGE_SELF)
    steps[step] = (ended.ru_utime - started.ru_utime, ended.ru_stime - started.ru_stime, wall)
    return result


def time_pipeline(frames: int, pieces: bool = False) -> None:
    """Print the CPU and wall time of each step of an open per frame and against the parse (module
    docstring), after a warm-up on a small dataset that pays the steps' costs once a process; with
    ``pieces``, those of the open's pieces too (:func:`open_pieces`)."""
    from ringlight.core import open_dataset
    from ringlight.core.dataset import cache
    from ringlight.core.dataset.checks import find_file_problems
    from ringlight.core.dataset.open_plan import plan_open

    steps = {}

    def timed(step, work):
        return measured(steps, step, work)

    with tempfile.TemporaryDirectory() as folder:
        warm, folder = Path(folder) / "warm", Path(folder) / "long"
        write_linked_dataset(warm, WARM_FRAMES)
        write_linked_dataset(folder, frames)
        read_manifest(folder)  # warm: the page cache, lazy imports
        small = read_manifest(warm)
        timed("warm-up", lambda: (find_file_problems(small), open_dataset(small, use_cache=False)))
        manifest = timed("parse", lambda: read_manifest(folder))
        shown, problems = timed("check", lambda: find_file_problems(manifest, keep=5))
        timed("plan", lambda: plan_open(manifest))
        timed("key", lambda: cache.stat_key(manifest, cache.manifest_key(manifest, 3.0)))
        dataset = timed("open", lambda: open_dataset(manifest, use_cache=False))
        if pieces:
            open_pieces(manifest, steps)
    if problems or not responses_match(dataset):
        raise SystemExit(f"the dataset did not open as written: {shown}")
    user, system, wall = steps.pop("warm-up")
    print(f"warm-up: the check and open of {WARM_FRAMES} frames first (imports, compiled kernels loaded), once a "
          f"process: {user + system:.2f} s of CPU, {wall:.2f} s wall")
    print(f"{frames} one-point frames on a 10 x 10 grid (hard links to 50 EXR files), us a frame: CPU of all threads "
          "(user + system, the system's in the kernel's calls) and wall, each against the parse's:")
    parse_cpu, parse_wall = sum(steps["parse"][:2]), steps["parse"][2]
    for step, (user, system, wall) in steps.items():
        seconds, us = user + system, 1e6 / frames
        print(f"  {step:7s} CPU {seconds * us:6.1f} ({user * us:5.1f} + {system * us:5.1f}) "
              f"{seconds / parse_cpu:4.1f} x   wall {wall * us:6.1f} {wall / parse_wall:4.1f} x")


WARM_FRAMES = 1000
"""Frames of the warm-up dataset (:func:`time_pipeline`)."""
PIECE_RUN = 1024
"""Frames of a run in :func:`open_pieces`: an open's group (a batch of 8192 frames on two readers)."""


def open_pieces(manifest, steps: dict) -> None:
    """Add to ``steps`` the open's pieces, on this thread, in runs of :data:`PIECE_RUN` frames:
    ``read``, the files read (:func:`.file_batch.read_run`: the system calls); ``+decode``, read
    again and decoded, scaled and marked (:meth:`.frame_batch.BatchDecoder.load`); ``scatter``, the
    decoded runs scattered into the responses."""
    import numpy as np
    from ringlight.core.dataset.assembly import Assembler, _Batch
    from ringlight.core.dataset.disc import disc_offsets
    from ringlight.core.dataset.file_batch import read_run
    from ringlight.core.dataset.frames import dataset_channels
    from ringlight.core.dataset.impulse_dataset import effective_max_radius
    from ringlight.core.dataset.scatter import scatter

    assembler = Assembler(manifest, disc_offsets(effective_max_radius(manifest)), channels=dataset_channels(manifest))
    decoder, shape = assembler.batches, (manifest.height, manifest.width)
    runs = [(start, min(start + PIECE_RUN, len(manifest.frames))) for start in range(0, len(manifest.frames), PIECE_RUN)]
    batch = _Batch(PIECE_RUN, *shape, len(assembler.offsets))
    responses, steady = np.zeros((*shape, len(assembler.offsets), 3), np.float32), np.zeros((*shape, 3))
    arguments = (assembler.dy, assembler.dx, assembler.offset_index, assembler.inverse_counts)
    measured(steps, "read", lambda: [read_run(decoder.reader.resolver, manifest.frames.files[start:stop],
                                              decoder.passed.header_bytes) for start, stop in runs])
    measured(steps, "+decode", lambda: [decoder.load(start, stop, 0, shape[0], batch.radiance, batch.owner, 0,
                                                     arguments) for start, stop in runs])
    measured(steps, "scatter", lambda: [scatter(responses, steady, batch.radiance, batch.owner, stop - start)
                                        for start, stop in runs])


def responses_match(dataset) -> bool:
    """Whether each point's own response is what its frames hold: point ``k = 10 y + x`` is lit
    by frames ``k + 100 j``, all links to file ``k % 50``, of value 0.01 (k % 50 + 1) in half
    floats, so their mean is that value (to the rounding of float32 sums)."""
    import numpy as np

    own = np.array([dataset.point(k // 10, k % 10)[0, 0] for k in range(100)])
    expected = np.float32(0.01 * (np.arange(100) % 50 + 1)).astype(np.float16).astype(np.float32)
    return bool(np.allclose(own, expected, rtol=1e-4, atol=0))  # 1000 float32 sums a point at 100 000 frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100_000)
    parser.add_argument("--hostile", action="store_true", help="time the fuzz tests' hostile values instead")
    parser.add_argument("--pipeline", action="store_true", help="time the steps of an open after the parse instead")
    parser.add_argument("--pieces", action="store_true", help="with --pipeline, time the open's pieces too")
    args = parser.parse_args()
    if args.hostile:
        time_hostile()
        return
    if args.pipeline:
        time_pipeline(args.frames, args.pieces)
        return
    for multiplexed in (False, True):
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            size = write_manifest(folder, args.frames, multiplexed)
            times = []
            for _ in range(3):
                started = time.perf_counter()
                manifest = read_manifest(folder)
                times.append(time.perf_counter() - started)
            tracemalloc.start()
            read_manifest(folder)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        kind = "multiplexed" if multiplexed else "one point per frame"
        points = sum(len(frame.lit) for frame in manifest.frames)
        print(f"{kind}: {len(manifest.frames)} frames, {points} lit points, {size / 2**20:.1f} MiB of JSON")
        print(f"  read_manifest    {min(times):.3f} s (best of 3)")
        print(f"  peak memory      {peak / 2**20:.0f} MiB (tracemalloc)")
        if not multiplexed:
            print(f"  target           {TARGET_S:.1f} s (10x faster than the {BEFORE_S:.0f} s before); "
                  f"ratio target / time = {TARGET_S / min(times):.1f}")


if __name__ == "__main__":
    main()
