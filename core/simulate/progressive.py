"""Progressive, resumable simulation: add photons until the transients are clean enough.

Photons come in batches of ``batch`` photons per lit point and channel, each batch an independent
:func:`.transport.simulate_transport` run (its own seed). Per batch the transient images T_r
(:mod:`.convergence`) are added to a running sum and sum of squares, so the noise of the mean of
``k`` batches is known per pixel from their spread: ``sqrt(mean over pixels of var(T) / k)``
over ``RMS(mean T)``, per radius (at least :data:`MIN_BATCHES` batches, so that the spread means
something even where every pixel sees the same response). The run stops once that is at most
the target at every radius up to the largest whose transient the window holds, or the time is
up, or it is cancelled. After every batch the sums are saved atomically to a checkpoint in the
user cache, named by everything the result depends on, so an interrupted run (Ctrl+C, a crash,
a power cut) keeps what it had and the same command takes it up again.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..checked_arrays import DamagedFile, load_checked, save_checked
from ..dataset.cache import user_cache_root
from ..device import Device, cpu_device
from ..errors import RinglightError
from ..rings.geometry import ring_geometry
from .convergence import transient_images
from .scene import Scene
from .transport import Transport, simulate_transport

CHECKPOINT_VERSION = 2
MIN_BATCHES = 8


class CheckpointError(RinglightError):
    """A checkpoint that cannot be read (reported with its path; the run then starts afresh)."""


@dataclass
class Sums:
    """The running sums of a progressive run over ``batches`` batches: windows
    (H, W, 2R+1, 2R+1, 3) and path-length images (bins, H, W, 3) of the per-batch means, and
    the transient images T_r, r = 0..radius, (radius + 1, H, W, 3) and their squares, all
    float64; ``seconds`` of simulation so far."""

    windows: np.ndarray
    truth: np.ndarray
    transients: np.ndarray
    squares: np.ndarray
    batches: int
    seconds: float

    def noise(self) -> np.ndarray:
        """(radius + 1,) estimated relative noise of T_r of the mean of all batches (inf with
        fewer than two batches)."""
        if self.batches < 2:
            return np.full(len(self.transients), np.inf)
        mean = self.transients / self.batches
        variance = np.maximum(self.squares / self.batches - mean * mean, 0.0) / (self.batches - 1)
        out = np.empty(len(mean))
        for r, (level, spread) in enumerate(zip(mean, variance)):
            valid = np.isfinite(level) & np.isfinite(spread)
            rms = math.sqrt(np.mean(level[valid] ** 2))
            out[r] = math.sqrt(np.mean(spread[valid])) / rms if rms > 0 else math.inf
        return out


def noise_radius(scene: Scene) -> int:
    """The largest r whose transient T_r = E_r - E_{r+1} lies within the window and is defined
    at some point of the grid (ring r + 1 has a member on it): on a grid smaller than the window
    the rings beyond it are NaN everywhere, their noise never known, and a run to a noise target
    never stopped (a 4 x 4 grid: "noise of T_r up to r = 11 at most inf" for good)."""
    window = math.ceil(scene.max_radius)
    for radius in range(max(0, window - 1), 0, -1):
        if any(max(abs(dy), abs(dx)) <= window and abs(dy) < scene.height and abs(dx) < scene.width
               for dy, dx in ring_geometry(float(radius + 1)).offsets):
            return radius
    return 0


def fingerprint(scene: Scene, seed: int, batch: int, estimator: str) -> str:
    """Hash of everything a progressive run's sums depend on."""
    digest = hashlib.sha256()
    fields = (CHECKPOINT_VERSION, scene.name, scene.height, scene.width, scene.pitch_mm, scene.depth, scene.n,
              scene.materials, scene.layers, scene.max_radius, scene.bin_step, scene.bin_count, scene.camera,
              scene.projector, scene.measure, seed, batch, estimator)
    digest.update(repr(fields).encode())
    digest.update(np.ascontiguousarray(scene.volume).tobytes())
    return digest.hexdigest()[:24]


def checkpoint_path(key: str) -> Path:
    """Where the checkpoint of a run with this :func:`fingerprint` lives."""
    return user_cache_root() / "simulations" / f"{key}.npz"


MAX_BATCHES = 2**31
"""Most batches a checkpoint may count (2^62 made the photon count overflow)."""
_ARRAYS = ("windows", "truth", "transients", "squares", "batches", "seconds")


def load_checkpoint(path: Path, scene: Scene | None = None) -> Sums | None:
    """The sums saved at ``path``, or None when there is none; raises :class:`CheckpointError`
    when the file is there but not a checkpoint this run wrote (:mod:`..checked_arrays`: the
    key is the file's name, the :func:`fingerprint` of the run), or its sums cannot be a run's:
    shapes other than ``scene``'s, a batch count outside 1..:data:`MAX_BATCHES`, sums not
    finite, squares below what the sums need (each sum of squares is at least the square of
    the sum over the batch count)."""
    try:
        data = load_checked(path, path.stem, _ARRAYS)
        if data is None:
            return None
        sums = _checked_sums(data, scene)
    except DamagedFile as error:
        raise CheckpointError(f"{path}: unreadable simulation checkpoint ({error})") from None
    return sums


def _checked_sums(data: dict[str, np.ndarray], scene: Scene | None) -> Sums:
    """``data`` as :class:`Sums`, or DamagedFile saying what no run could have saved."""
    windows, truth, transients, squares = (data[name] for name in _ARRAYS[:4])
    batches, seconds = data["batches"], data["seconds"]
    if batches.shape != () or batches.dtype.kind not in "iu" or not 1 <= int(batches) <= MAX_BATCHES:
        raise DamagedFile(f"a batch count of {batches!s} is not 1 to {MAX_BATCHES}")
    if seconds.shape != () or seconds.dtype.kind != "f" or not 0 <= float(seconds) < math.inf:
        raise DamagedFile(f"{seconds!s} seconds of simulation")
    if (windows.ndim != 5 or truth.ndim != 4 or transients.ndim != 4 or squares.shape != transients.shape
            or not all(array.dtype == np.float64 for array in (windows, truth, transients, squares))
            or transients.shape[1:] != windows.shape[:2] + windows.shape[4:] or truth.shape[1:] != transients.shape[1:]):
        raise DamagedFile("its arrays do not fit together")
    if scene is not None and transients.shape[:3] != (noise_radius(scene) + 1, scene.height, scene.width):
        raise DamagedFile("its arrays are not of this scene's size")
    # T_r is NaN where ring r or r + 1 has no member on the grid, in every batch alike.
    if (not np.isfinite(windows).all() or not np.isfinite(truth).all() or np.isinf(transients).any()
            or np.isinf(squares).any() or not np.array_equal(np.isnan(transients), np.isnan(squares))):
        raise DamagedFile("its sums are not finite")
    count = int(batches)
    if np.any(squares * count < transients * transients * (1 - 1e-9) - 1e-300):
        raise DamagedFile("its sums of squares are below their sums' squares")
    return Sums(windows, truth, transients, squares, count, float(seconds))


def save_checkpoint(path: Path, sums: Sums) -> None:
    """Write ``sums`` to ``path`` atomically (replacing the previous checkpoint), with the run's
    key (the file's name) and a digest (:mod:`..checked_arrays`)."""
    save_checked(path, path.stem, {"windows": sums.windows, "truth": sums.truth, "transients": sums.transients,
                                   "squares": sums.squares, "batches": np.int64(sums.batches),
                                   "seconds": np.float64(sums.seconds)})


@dataclass(frozen=True)
class Status:
    """What a progressive run reports after each batch: photons per point so far, the noise
    per radius r = 0..radius (:meth:`Sums.noise`), its largest value, seconds, and whether
    the run took up a checkpoint."""

    photons: int
    noise: np.ndarray
    radius: int
    seconds: float
    resumed: bool

    @property
    def worst(self) -> float:
        return float(np.max(self.noise))


def simulate_until(scene: Scene, target: float | None = None, seconds: float | None = None, *, batch: int = 50,
                   seed: int | None = None, estimator: str = "reference",
                   report: Callable[[Status], None] | None = None,
                   progress: Callable[[float], None] | None = None,
                   device: Device | None = None) -> tuple[Transport, Status]:
    """Simulate ``scene`` in batches until the estimated noise of T_r is at most ``target`` for
    every r up to :func:`noise_radius` (after at least :data:`MIN_BATCHES` batches) or
    ``seconds`` of simulation (this session's and the checkpoint's together) have passed; at
    least two batches are run. Resumes from, and updates, the checkpoint of the same run
    (:func:`forget_checkpoint` removes it once the result is saved). ``progress`` gets fractions
    within one batch and may raise to cancel (the batches done are kept). ``device`` runs this
    session's batches (:func:`.transport.simulate_transport`). Returns the transport of all photons
    and the last status."""
    if target is None and seconds is None:
        raise ValueError("simulate_until needs a noise target, a time, or both")
    seed = scene.seed if seed is None else seed
    path = checkpoint_path(fingerprint(scene, seed, batch, estimator))
    sums = load_checkpoint(path, scene)
    radius = noise_radius(scene)
    radii = np.arange(radius + 1)
    status = None
    if sums is not None:
        status = Status(sums.batches * batch, sums.noise(), radius, sums.seconds, True)
        if report is not None:
            report(status)
    while status is None or not _done(status, sums.batches, target, seconds):
        started = time.perf_counter()
        run = simulate_transport(scene, photons=batch, seed=_batch_seed(seed, sums.batches if sums else 0),
                                 estimator=estimator, progress=progress, device=device)
        windows = run.windows.astype(np.float64)
        transients = transient_images(windows, radii)
        if sums is None:
            sums = Sums(np.zeros_like(windows), np.zeros(run.path_length_images.shape), np.zeros_like(transients),
                        np.zeros_like(transients), 0, 0.0)
        sums.windows += windows
        sums.truth += run.path_length_images
        sums.transients += transients
        sums.squares += transients * transients
        sums.batches += 1
        sums.seconds += time.perf_counter() - started
        save_checkpoint(path, sums)
        status = Status(sums.batches * batch, sums.noise(), radius, sums.seconds, status is not None and status.resumed)
        if report is not None:
            report(status)
    transport = Transport(
        scene=scene, photons=status.photons, seed=seed, window_radius=math.ceil(scene.max_radius),
        windows=(sums.windows / sums.batches).astype(np.float32),
        path_length_images=(sums.truth / sums.batches).astype(np.float32),
        seconds=sums.seconds, measure=scene.measure, estimator=estimator,
        device=(device or cpu_device()).name)
    return transport, status


def forget_checkpoint(scene: Scene, seed: int | None, batch: int, estimator: str) -> None:
    """Remove the checkpoint of a run once its dataset is written (ringlight's own file)."""
    seed = scene.seed if seed is None else seed
    checkpoint_path(fingerprint(scene, seed, batch, estimator)).unlink(missing_ok=True)


def _done(status: Status, batches: int, target: float | None, seconds: float | None) -> bool:
    if batches < 2:
        return False
    return ((target is not None and batches >= MIN_BATCHES and status.worst <= target)
            or (seconds is not None and status.seconds >= seconds))


def _batch_seed(seed: int, index: int) -> int:
    """The seed of batch ``index`` (batch 0 keeps the run's seed)."""
    return seed + (index << 32)

