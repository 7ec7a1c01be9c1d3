"""Independent reference implementations for the tests.

Nothing here imports ringlight: datasets are written with OpenEXR and json directly, and ring
light / transient images are computed by brute force straight from FORMAT.md's definitions.
"""

from __future__ import annotations

import functools
import json
import math
import threading
from pathlib import Path

import numpy as np
import OpenEXR


def write_exr(path: Path, channels: dict[str, np.ndarray], half: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    dtype = np.float16 if half else np.float32
    pixels = {name: np.ascontiguousarray(plane, dtype=dtype) for name, plane in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, pixels) as exr:
        exr.write(str(path))


def write_rgb(path: Path, image: np.ndarray, half: bool = False) -> None:
    write_exr(path, {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2]}, half)


def random_impulses(rng, height, width, support, missing=0.0):
    """Random impulse images {(y, x): (H, W, 3) float32}, zero beyond ``support`` of q.

    A fraction ``missing`` of points gets no entry (a missing point). ``rng`` is a numpy Generator
    whose bit generator can ``advance`` (default_rng's PCG64)."""
    # Each image is falloff x uniform(0.2, 1) drawn over the whole grid, row after row; only the rows
    # within the support are drawn here, and the generator advanced past the others (one 64-bit
    # draw a double), which gives the same images and leaves the generator where the whole draw
    # would (a 96 x 80 grid: 5.8 CPU-s before, 0.9 now).
    dy, dx = np.mgrid[1 - height:height, 1 - width:width]
    distances = np.hypot(dy, dx)  # of every offset a grid can hold, at [dy + H - 1, dx + W - 1]
    falloffs = np.exp(-distances / 3.0)[..., None]
    reach, row_draws = math.floor(support), width * 3
    impulses = {}
    for y in range(height):
        top, bottom = max(y - reach, 0), min(y + reach + 1, height)
        rows = slice(height - 1 - y + top, height - 1 - y + bottom)
        for x in range(width):
            if rng.random() < missing:
                continue
            columns = slice(width - 1 - x, 2 * width - 1 - x)
            image = np.zeros((height, width, 3), np.float32)
            band = image[top:bottom]
            rng.bit_generator.advance(top * row_draws)
            band[...] = falloffs[rows, columns] * rng.uniform(0.2, 1.0, band.shape)
            rng.bit_generator.advance((height - bottom) * row_draws)
            band[distances[rows, columns] > support] = 0.0
            impulses[(y, x)] = image
    return impulses


def lattice_groups(points, spacing):
    """Group points into frames whose members are >= ``spacing`` apart on both axes' lattice."""
    groups = {}
    for y, x in points:
        groups.setdefault((y % spacing, x % spacing), []).append((y, x))
    return list(groups.values())


def write_dataset(folder: Path, height, width, impulses, *, max_radius=None, multiplex=False,
                  half=False, extra=None):
    """Write impulses as a FORMAT.md dataset, one point per frame or multiplexed on a lattice."""
    folder.mkdir(parents=True, exist_ok=True)
    if multiplex:
        groups = lattice_groups(sorted(impulses), int(math.floor(2 * max_radius)) + 1)
    else:
        groups = [[q] for q in sorted(impulses)]
    frames = []
    for index, group in enumerate(groups):
        image = sum(impulses[q] for q in group)
        name = f"frames/{index:05d}.exr"
        write_rgb(folder / name, image, half)
        frames.append({"file": name, "lit": [list(q) for q in group]})
    manifest = {"format": "ringlight-impulse", "version": 1,
                "grid": {"height": height, "width": width}, "frames": frames}
    if max_radius is not None:
        manifest["max_radius"] = max_radius
    manifest.update(extra or {})
    (folder / "dataset.json").write_text(json.dumps(manifest))
    return manifest



def write_truth_dataset(folder: Path, height, width, impulses, truth_images, max_radius):
    """A one-point-per-frame dataset with ground-truth path-length bins [i, i + 1), one a
    ``truth_images[i]`` ((H, W, 3) linear RGB)."""
    entries = []
    for index, image in enumerate(truth_images):
        write_rgb(folder / f"truth/len_{index:03d}.exr", image)
        entries.append({"file": f"truth/len_{index:03d}.exr", "min": float(index), "max": float(index + 1)})
    write_dataset(folder, height, width, impulses, max_radius=max_radius,
                  extra={"ground_truth": {"path_length_images": entries}})
    return folder

def brute_ring_image(impulses, height, width, radius, thickness=1.0, weight=None):
    """E_r by the definition: loop over every pixel and every lit point.

    ``weight(dy, dx)`` gives anti-aliased weights; None is the default ring (weight 1 inside
    r - w/2 <= |d| < r + w/2)."""
    out = np.full((height, width, 3), np.nan)
    if weight is None:
        # The same sums in the same order (lit point by lit point), every pixel at once: a
        # 48 x 48 grid of 2304 points takes 0.07 CPU-s, not 2.2.
        yy, xx = np.mgrid[:height, :width]
        total, weights = np.zeros((height, width, 3)), np.zeros((height, width))
        for (qy, qx), image in impulses.items():
            distance = np.hypot(qy - yy, qx - xx)
            ring = (radius - thickness / 2 <= distance) & (distance < radius + thickness / 2)
            total[ring] += image[ring]
            weights[ring] += 1.0
        seen = weights > 0
        out[seen] = total[seen] / weights[seen, None]
        return out
    for y in range(height):
        for x in range(width):
            total, weights = np.zeros(3), 0.0
            for (qy, qx), image in impulses.items():
                dy, dx = qy - y, qx - x
                w = weight(dy, dx)
                if w > 0:
                    total += w * image[y, x]
                    weights += w
            if weights > 0:
                out[y, x] = total / weights
    return out


def assert_slopes_are_central_differences(forward, mua, step: float = 1e-6, rtol: float = 1e-5) -> None:
    """A forward model's ``profile(mua, derivatives=True)`` slopes (R, L) against central
    differences of its own profile, layer by layer."""
    _, slopes = forward.profile(mua, derivatives=True)
    for k in range(len(mua)):
        shift = np.zeros(len(mua))
        shift[k] = step
        numeric = (forward.profile(mua + shift) - forward.profile(mua - shift)) / (2 * step)
        np.testing.assert_allclose(slopes[:, k], numeric, rtol=rtol)


def supersampled_annulus_weight(radius, thickness, samples=64):
    """Pixel coverage of the annulus by supersampling (an independent check of exact areas);
    each offset's weight is computed once (brute-force images ask for it at every pixel)."""
    inner, outer = max(radius - thickness / 2, 0.0), radius + thickness / 2
    u = (np.arange(samples) + 0.5) / samples - 0.5

    @functools.cache
    def weight(dy, dx):
        if math.hypot(dy, dx) > outer + 1 or math.hypot(dy, dx) < inner - 1:
            return 0.0
        yy, xx = np.meshgrid(dy + u, dx + u, indexing="ij")
        distance = np.hypot(yy, xx)
        return float(((distance >= inner) & (distance < outer)).mean())

    return weight


def edit_manifest(folder: Path, change) -> None:
    """Apply ``change(manifest_dict)`` to ``folder/dataset.json`` in place (tests break one thing)."""
    path = folder / "dataset.json"
    manifest = json.loads(path.read_text())
    change(manifest)
    path.write_text(json.dumps(manifest))


def assert_same_for_any_thread_count(simulate):
    """``simulate()`` (a Transport) gives bit-identical frames and truth on 1 and on all threads;
    returns the Transport."""
    import numba

    results = []
    for threads in (1, numba.config.NUMBA_NUM_THREADS):
        numba.set_num_threads(threads)
        try:
            results.append(simulate())
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert np.array_equal(results[0].windows, results[1].windows)
    assert np.array_equal(results[0].path_length_images, results[1].path_length_images)
    return results[0]


class CountingReads:
    """Counts EXR frame decodes, alone or in a run of small frames (the work the cache exists to
    avoid), from whichever thread decodes them: an open decodes its frames in a pool of threads, and
    an unguarded ``+=`` from two of them lost a run's count now and then (24 of 30 frames counted
    once in a loaded CI)."""

    def __init__(self, monkeypatch):
        import ringlight.core.dataset.frames as frames_module
        from ringlight.core.dataset.frame_batch import BatchDecoder

        self.count = 0
        lock = threading.Lock()
        original, original_run = frames_module.read_exr_channels, BatchDecoder.load

        def counted(*args, **kwargs):
            with lock:
                self.count += 1
            return original(*args, **kwargs)

        def counted_run(decoder, *args, **kwargs):
            run, status, bad = original_run(decoder, *args, **kwargs)
            with lock:
                self.count += int(np.count_nonzero(status == 0))  # the others are read alone, counted above
            return run, status, bad

        monkeypatch.setattr(frames_module, "read_exr_channels", counted)
        monkeypatch.setattr(BatchDecoder, "load", counted_run)
