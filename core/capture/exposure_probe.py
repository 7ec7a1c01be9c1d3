"""Choosing the exposure bracket from a few probe captures of a typical impulse frame.

- shortest: the brightest impulse (the lit points themselves) at ``TARGET_FILL`` of the sensor's
  range above black;
- longest: the faint light near ``max_radius`` from the lit points (the ``FAINT_PERCENTILE``
  of the lit neighbourhoods' signal, measured at the longest exposure the camera allows without
  it saturating) at ``FAINT_COUNTS`` counts above black;
- brackets spaced by a factor ``RATIO`` between them, at most ``MAX_BRACKETS``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .hardware import Camera, Projector
from .hdr import bracket_exposures
from .projector_check import near_lit
from .scan import as_rgb, capture_with_timeout
from .scan_plan import ScanPlan

TARGET_FILL = 0.8
FAINT_PERCENTILE = 5.0
FAINT_COUNTS = 20.0
RATIO = 4.0
MAX_BRACKETS = 6


@dataclass(frozen=True)
class ExposurePlan:
    """The bracket (seconds), the merge's noise floor (counts), the brightest and faint light
    (counts per second) and ``capture_overhead``: the seconds each probe capture took beyond its
    exposure (readout, transfer, the camera's own frame period), for the scan's time estimate."""

    exposures: tuple[float, ...]
    noise_floor: float
    peak_rate: float
    faint_rate: float
    capture_overhead: float = 0.0


def probe_exposures(camera: Camera, projector: Projector, plan: ScanPlan, mapping: np.ndarray) -> ExposurePlan:
    """Probe with the plan's first lattice frame (see module docstring).

    ``mapping`` (rows, cols, 2) grid positions of camera pixels (NaN where none) tells which camera
    pixels look within max_radius of a lit point.
    """
    low, high = camera.exposure_range
    black, saturation = camera.black_level, camera.saturation_level
    lit = plan.frames()[0]
    overheads = []

    def capture(exposure: float) -> np.ndarray:
        started = time.monotonic()
        frame = as_rgb(capture_with_timeout(camera, exposure))
        overheads.append(max(0.0, time.monotonic() - started - exposure))
        return frame

    projector.show_black()
    noise = float(np.std(capture(low).mean(-1)))
    projector.show(plan.pattern(lit, projector.size))
    exposure = float(np.sqrt(low * high))
    while True:
        frame = capture(exposure).max(-1)
        peak = float(frame.max() - black)
        if frame.max() < saturation - 0.5 or exposure <= low:
            break
        exposure = max(low, exposure / 8)
    peak_rate = max(peak, 1.0) / exposure
    shortest = float(np.clip(TARGET_FILL * (saturation - black) / peak_rate, low, high))

    near = near_lit(mapping, lit, plan.max_radius)
    long_frame = capture(high).mean(-1) - black
    long_exposure = high
    while (long_frame >= saturation - black - 0.5).mean() > 0.5 and long_exposure > shortest:
        long_exposure = max(shortest, long_exposure / 8)
        long_frame = capture(long_exposure).mean(-1) - black
    signal = long_frame[near] if near.any() else long_frame.ravel()
    faint_rate = max(float(np.percentile(signal, FAINT_PERCENTILE)), noise, 1e-9) / long_exposure
    longest = float(np.clip(FAINT_COUNTS / faint_rate, shortest, high))
    exposures = bracket_exposures(shortest, longest, RATIO)
    if len(exposures) > MAX_BRACKETS:
        exposures = list(np.geomspace(shortest, longest, MAX_BRACKETS))
    projector.show_black()
    return ExposurePlan(tuple(float(e) for e in exposures), 3.0 * noise, peak_rate, faint_rate,
                        float(np.median(overheads)))
