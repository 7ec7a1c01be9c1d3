"""Benchmark of peak memory for a big camera (not a test: prints figures from one run).

A camera-space dataset (FORMAT.md ``frame_space`` "camera") from a 20-megapixel camera
(5472 x 3648, HALF frames, no compression) over a 640 x 480 grid, multiplexed on a lattice at
max_radius 4.5, and a 4-radius transient stack. Every frame entry names the same frame file
(the work per frame, decoding and averaging onto the grid, is the same; the disk holds one).

The measurement runs in a fresh process: its peak RSS (``ru_maxrss``) after imports and a small
warm-up (numba compilation) is the baseline; the increment while opening the dataset and
computing the stack is compared with the issue's budget, 3 x one frame's float32 size
(5472 x 3648 x 3 x 4 bytes = 240 MB) plus the response array.

    python benchmarks/bench_camera_memory.py [--camera 5472x3648] [--grid 640x480] [--frames 20]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR

MiB = 2**20


def write_dataset(folder: Path, camera: tuple[int, int], grid: tuple[int, int], frames: int,
                  max_radius: float) -> None:
    """The dataset: a mapping that spreads the camera evenly over the grid, one frame file."""
    folder.mkdir(parents=True, exist_ok=True)
    (cam_h, cam_w), (grid_h, grid_w) = camera, grid
    rows = ((np.arange(cam_h, dtype=np.float32) + 0.5) * grid_h / cam_h - 0.5)[:, None]
    cols = ((np.arange(cam_w, dtype=np.float32) + 0.5) * grid_w / cam_w - 0.5)[None, :]
    mapping = {"y": np.ascontiguousarray(np.broadcast_to(rows, camera)),
               "x": np.ascontiguousarray(np.broadcast_to(cols, camera))}
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, mapping) as exr:
        exr.write(str(folder / "mapping.exr"))
    del mapping
    yy, xx = np.mgrid[:cam_h, :cam_w].astype(np.float32)
    frame = {c: (np.sin(yy * (k + 1) / 700.0) * np.cos(xx / 900.0) + 1.5).astype(np.float16)
             for k, c in enumerate("RGB")}
    del yy, xx
    (folder / "frames").mkdir(exist_ok=True)
    with OpenEXR.File(header, frame) as exr:
        exr.write(str(folder / "frames" / "frame.exr"))
    spacing = int(2 * max_radius) + 1
    entries = []
    for index in range(frames):
        oy, ox = divmod(index % (spacing * spacing), spacing)
        lit = [[y, x] for y in range(oy, grid_h, spacing) for x in range(ox, grid_w, spacing)]
        entries.append({"file": "frames/frame.exr", "lit": lit})
    manifest = {"format": "ringlight-impulse", "version": 1, "grid": {"height": grid_h, "width": grid_w},
                "frame_space": "camera", "mapping": "mapping.exr", "max_radius": max_radius, "frames": entries}
    (folder / "dataset.json").write_text(json.dumps(manifest))


def measure(folder: str) -> None:
    """In a fresh process: baseline RSS, then open + 4-radius transient stack; prints JSON."""
    from ringlight.core import open_dataset, transient_stack
    from ringlight.core.dataset.frames import CameraMapping

    # Warm-up: compile the camera kernels on a tiny mapping (their memory is not the dataset's).
    warm = CameraMapping(np.zeros((4, 4), np.float32), np.zeros((4, 4), np.float32), (2, 2))
    warm.to_grid(np.ones((4, 4, 3), np.float32))
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    start = time.perf_counter()
    dataset = open_dataset(folder, use_cache=False)
    stack = transient_stack(dataset, np.arange(4.0), 1.0)
    elapsed = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"baseline": baseline, "peak": peak, "responses": dataset.responses.nbytes,
                      "mapping": _mapping_bytes(folder),  # after the peak is taken
                      "seconds": elapsed, "undefined": int(np.isnan(stack.images).any(-1).sum())}))


def _mapping_bytes(folder: str) -> int:
    """Bytes the compact CameraMapping keeps for this dataset (two int32 per seen pixel)."""
    from ringlight.core.dataset.exr import read_exr_channels
    from ringlight.core.dataset.frames import CameraMapping
    from ringlight.core.dataset.manifest import read_manifest

    manifest = read_manifest(folder)
    yx = read_exr_channels(Path(folder) / "mapping.exr", ("y", "x"))
    mapping = CameraMapping(yx[..., 0], yx[..., 1], (manifest.height, manifest.width))
    return mapping.camera_pixels.nbytes + mapping.grid_index.nbytes + mapping.counts.nbytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--camera", default="5472x3648", help="camera WIDTHxHEIGHT (default 20 MP)")
    parser.add_argument("--grid", default="640x480", help="grid WIDTHxHEIGHT")
    parser.add_argument("--frames", type=int, default=20, help="frame entries (lattice offsets)")
    parser.add_argument("--max-radius", type=float, default=4.5)
    parser.add_argument("--measure", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        measure(args.measure)
        return
    cam_w, cam_h = (int(v) for v in args.camera.split("x"))
    grid_w, grid_h = (int(v) for v in args.grid.split("x"))
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        write_dataset(Path(folder), (cam_h, cam_w), (grid_h, grid_w), args.frames, args.max_radius)
        print(f"wrote a {cam_w} x {cam_h} camera dataset ({args.frames} frames over a {grid_w} x {grid_h} grid) "
              f"in {time.perf_counter() - start:.0f} s")
        result = subprocess.run([sys.executable, __file__, "--measure", folder], capture_output=True, text=True,
                                check=True)
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    frame = cam_h * cam_w * 3 * 4
    budget = 3 * frame + figures["responses"]
    increment = figures["peak"] - figures["baseline"]
    print(f"open + 4-radius transient stack: {figures['seconds']:.1f} s")
    print(f"one frame (float32)   {frame / MiB:8.1f} MiB")
    print(f"response array        {figures['responses'] / MiB:8.1f} MiB")
    print(f"camera mapping        {figures['mapping'] / MiB:8.1f} MiB (int32 pixel and grid indices, int32 counts)")
    print(f"budget                {budget / MiB:8.1f} MiB (3 x frame + responses)")
    print(f"baseline RSS          {figures['baseline'] / MiB:8.1f} MiB (imports, numba warm-up)")
    print(f"peak RSS              {figures['peak'] / MiB:8.1f} MiB")
    print(f"peak - baseline       {increment / MiB:8.1f} MiB: {'within' if increment <= budget else 'OVER'} "
          f"budget ({increment / budget:.0%})")


if __name__ == "__main__":
    main()
