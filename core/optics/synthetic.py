"""Impulse datasets in memory made from one impulse response: a laterally homogeneous surface
whose every lit point sees the same response, with independent noise on each response value (for
validation, tests and benchmarks of the optical maps: no frames, no EXR)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset.disc import disc_offsets
from ..dataset.impulse_dataset import ImpulseDataset
from ..dataset.manifest import Manifest
from ..dataset.sample import Sample


def homogeneous_dataset(kernel: np.ndarray, height: int, width: int, *, max_radius: float,
                        member_noise: np.ndarray | None = None, seed: int = 0, pitch_mm: float | None = None,
                        n: float | None = None, g: float | None = None) -> ImpulseDataset:
    """A dataset whose lit point ``q`` gives ``I_q(p) = kernel[S // 2 + py - qy, S // 2 + px - qx]``.

    Parameters
    ----------
    kernel
        (S, S, 3) the impulse response around its lit pixel (S odd, ``S // 2 >= max_radius``),
        e.g. a simulated window (:class:`ringlight.core.simulate.transport.Transport` ``windows``).
    height, width, max_radius
        The grid and the reach of the responses (grid steps).
    member_noise
        (M,) relative standard deviation of each response value by its distance from the lit
        point rounded to an integer (Gaussian, independent); None for none.
    pitch_mm, n, g
        The manifest's ``grid.pitch_mm`` and ``sample`` key.

    Returns
    -------
    ImpulseDataset
        In memory (``H * W * K * 12`` bytes, K the offsets within max_radius), every point lit.
    """
    offsets = disc_offsets(max_radius)
    half = kernel.shape[0] // 2
    values = kernel[half - offsets[:, 0], half - offsets[:, 1]].astype(np.float32)  # (K, 3)
    responses = np.empty((height, width, len(offsets), 3), np.float32)
    rng = np.random.default_rng(seed)
    relative = None
    if member_noise is not None:
        distance = np.rint(np.hypot(offsets[:, 0], offsets[:, 1])).astype(int)
        relative = np.asarray(member_noise, np.float32)[np.minimum(distance, len(member_noise) - 1)]
    for y in range(height):
        row = np.broadcast_to(values, (width,) + values.shape)
        if relative is not None:
            noise = rng.standard_normal((width, len(offsets), 3), dtype=np.float32)
            row = row * (1.0 + relative[None, :, None] * noise)
        responses[y] = row
        # Responses from points outside the grid are 0 (the response model's invariant).
        qy = y + offsets[:, 0]
        qx = np.arange(width)[:, None] + offsets[None, :, 1]
        outside = (qy[None, :] < 0) | (qy[None, :] >= height) | (qx < 0) | (qx >= width)
        responses[y][outside] = 0.0
    manifest = Manifest(folder=Path("synthetic"), height=height, width=width, pitch_mm=pitch_mm, colorspace="sRGB",
                        frame_space="grid", mapping=None, max_radius=float(max_radius), frames=(), dark=None,
                        ground_truth=None, notes=None, sample=Sample(n, g))
    return ImpulseDataset(manifest, float(max_radius), offsets, responses, np.ones((height, width), np.int32),
                          np.ones((height, width), bool))
