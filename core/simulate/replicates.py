"""Independent replicates of a simulation: the photons of a run split into ``K`` runs of their own
seeds, whose mean is the result and whose spread is its noise, noise shared by the lit points
included (the reference estimator gives every point of a layered scene one kernel, so the spread
of a ring's members shows none of it). Written as the dataset's replicates (the frame key
``replicate``; :mod:`ringlight.core.dataset.replicates` reads them)."""

from __future__ import annotations

import math

import numpy as np

from ..dataset.impulse_dataset import ProgressCallback
from ..device import Device
from ..errors import RinglightError
from .convergence import transient_images
from .scene import Scene
from .transport import Transport, simulate_transport

MAX_REPLICATES = 64


def replicate_seed(seed: int, index: int) -> int:
    """The seed of replicate ``index`` (replicate 0 keeps the run's seed)."""
    return seed + (index << 32)


def simulate_replicates(scene: Scene, photons: int, replicates: int, seed: int | None = None,
                        progress: ProgressCallback | None = None, estimator: str = "reference",
                        device: Device | None = None) -> Transport:
    """``replicates`` independent runs of ``photons // replicates`` photons per lit point and
    channel each (``photons`` must be at least ``replicates``); the transport of their mean, with
    each run's windows in :attr:`.transport.Transport.replicates`. ``progress`` gets the fraction
    done and may raise ``Cancelled``; ``device`` runs them (the CPU when None)."""
    if not 2 <= replicates <= MAX_REPLICATES:
        raise RinglightError(f"replicates must be 2 to {MAX_REPLICATES}, got {replicates}")
    if photons < replicates:
        raise RinglightError(f"{replicates} replicates need at least {replicates} photons per point, got {photons}")
    seed = scene.seed if seed is None else seed
    share = photons // replicates
    runs = []
    for index in range(replicates):
        step = None if progress is None else (lambda fraction, index=index: progress((index + fraction) / replicates))
        runs.append(simulate_transport(scene, share, replicate_seed(seed, index), step, estimator=estimator,
                                       device=device))
    windows = [run.windows for run in runs]
    return Transport(
        scene=scene, photons=share * replicates, seed=seed, window_radius=runs[0].window_radius,
        windows=np.mean(windows, axis=0, dtype=np.float64).astype(np.float32),
        path_length_images=np.mean([run.path_length_images for run in runs], axis=0, dtype=np.float64
                                   ).astype(np.float32),
        seconds=sum(run.seconds for run in runs), measure=runs[0].measure, estimator=estimator,
        replicates=tuple(windows), device=runs[0].device)


def replicate_transient_noise(transport: Transport, radius: int) -> np.ndarray:
    """(radius + 1,) relative noise of T_r (r = 0 .. ``radius``) of the replicates' mean: the RMS
    over pixels of its standard error from the replicates' spread, over the RMS of T_r (as
    :meth:`.progressive.Sums.noise` has it for batches)."""
    radii = np.arange(radius + 1)
    stack = np.stack([transient_images(windows.astype(np.float64), radii) for windows in transport.replicates])
    count = len(stack)
    mean = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / count
    noise = np.empty(len(radii))
    for r in range(len(radii)):
        valid = np.isfinite(mean[r]) & np.isfinite(variance[r])
        rms = math.sqrt(np.mean(mean[r][valid] ** 2))
        noise[r] = math.sqrt(np.mean(variance[r][valid])) / rms if rms > 0 else math.inf
    return noise
