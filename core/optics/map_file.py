"""The optical-property maps as one EXR file of named channels, as ``ringlight optics --out``
and the explorer's File > Export optical maps write them (docs/guide/optics.md)."""

from __future__ import annotations

import os

import numpy as np

from ..atomic import atomic_file
from ..dataset.exr import write_exr_channels
from .maps import OpticalMaps


def map_channels(maps: OpticalMaps) -> dict[str, np.ndarray]:
    """The maps as named (H, W) channels: ``mua.R``, ..., ``mua.R_se``, ..., ``musp.B_se`` (per mm
    or per grid step, :attr:`OpticalMaps.units`), ``determined.R`` ... (1 where determined, else
    0) and ``complete`` (1 where every ring lies whole on the grid and lit, 0 where the grid's edge
    or an unlit point cuts one: a biased fit)."""
    channels = {}
    for name, values, errors in (("mua", maps.mua, maps.mua_se), ("musp", maps.musp, maps.musp_se)):
        for c, channel in enumerate(maps.channels):
            channels[f"{name}.{channel}"] = values[..., c]
            channels[f"{name}.{channel}_se"] = errors[..., c]
    for c, channel in enumerate(maps.channels):
        channels[f"determined.{channel}"] = maps.determined[..., c].astype(np.float32)
    channels["complete"] = maps.complete.astype(np.float32)
    return channels


def map_attributes(maps: OpticalMaps) -> dict[str, str | float]:
    """What the numbers of :func:`map_channels` mean, as EXR header attributes:
    ``ringlight.units`` (``"per_mm"`` or ``"per_grid_step"``), ``ringlight.pitch_mm`` (with
    per-mm units), ``ringlight.n``, ``ringlight.g``, ``ringlight.noise`` (where the standard
    errors of E_r came from) and ``ringlight.scale`` (the rig's scale per channel, ``"R G B"``:
    1 1 1 without a calibration)."""
    attributes = {"ringlight.units": maps.units, "ringlight.n": float(maps.n), "ringlight.g": float(maps.g),
                  "ringlight.noise": maps.noise_source,
                  "ringlight.scale": " ".join(f"{float(s):.9g}" for s in maps.scale)}
    if maps.pitch_mm is not None:
        attributes["ringlight.pitch_mm"] = float(maps.pitch_mm)
    return attributes


def write_maps(maps: OpticalMaps, path: str | os.PathLike, *, overwrite: bool = False) -> None:
    """Write :func:`map_channels` of ``maps`` with :func:`map_attributes` to the EXR file ``path``
    atomically (an existing ``path`` is replaced only with ``overwrite``:
    :func:`ringlight.core.atomic.atomic_file`)."""
    with atomic_file(path, overwrite=overwrite) as temporary:
        write_exr_channels(temporary, map_channels(maps), attributes=map_attributes(maps))
