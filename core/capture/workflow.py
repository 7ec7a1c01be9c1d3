"""The capture workflow, step by step (the wizard runs the steps one at a time, the CLI in a row).

1. devices open; 2. an exposure for the white pattern; 3. Gray code correspondence; 4. the grid
(region of interest, max_radius), its mapping and the scan plan with a probed exposure bracket;
5. the scan (resumable); the result is an impulse dataset (docs/format) in camera frame space.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataset.exr import read_exr_channels
from .correspondence import Correspondence, capture_gray_code, decode_gray_code
from .exposure_probe import ExposurePlan, probe_exposures
from .hardware import Camera, Projector
from .projector_check import CHECK_EVERY
from .scan import Scan, ScanProgress, as_rgb, capture_with_timeout
from .scan_plan import (
    PLAN_NAME,
    SCAN_FOLDER,
    ScanError,
    ScanPlan,
    check_plan,
    read_plan,
)

WHITE_FILL = 0.6


def white_exposure(camera: Camera, projector: Projector) -> float:
    """An exposure at which the all-white pattern fills about WHITE_FILL of the range (for the
    Gray code captures), found by factors of 4 from the shortest exposure."""
    low, high = camera.exposure_range
    projector.show_white()
    exposure = low
    while True:
        peak = float(as_rgb(capture_with_timeout(camera, exposure)).max()) - camera.black_level
        span = camera.saturation_level - camera.black_level
        if peak >= WHITE_FILL * span or exposure >= high:
            break
        exposure = min(high, exposure * max(2.0, min(4.0, WHITE_FILL * span / max(peak, 1.0))))
    projector.show_black()
    return exposure


def measure_correspondence(camera: Camera, projector: Projector,
                           progress: Callable[[float], None] | None = None) -> Correspondence:
    exposure = white_exposure(camera, projector)
    captures, black, white = capture_gray_code(camera, projector, exposure, progress)
    return decode_gray_code(captures, black, white, projector.size)


@dataclass(frozen=True, eq=False)
class PlannedScan:
    plan: ScanPlan
    mapping: np.ndarray
    exposure: ExposurePlan


def plan_scan(camera: Camera, projector: Projector, correspondence: Correspondence,
              roi: tuple[int, int, int, int], max_radius: float) -> PlannedScan:
    """The scan plan over ``roi`` with a probed exposure bracket."""
    draft = ScanPlan(tuple(int(v) for v in roi), float(max_radius), (1.0,))
    check_plan(draft, projector.size)
    mapping = correspondence.mapping(draft.roi)
    if not np.isfinite(mapping[..., 0]).any():
        raise ScanError(f"no camera pixel sees the region {list(draft.roi)}")
    exposure = probe_exposures(camera, projector, draft, mapping)
    plan = ScanPlan(draft.roi, draft.max_radius, exposure.exposures, exposure.noise_floor)
    return PlannedScan(plan, mapping, exposure)


def resume_scan(out) -> Scan:
    """The unfinished scan in ``out``, from its stored plan, camera description and mapping."""
    if not (Path(out) / SCAN_FOLDER / PLAN_NAME).is_file():
        raise ScanError(f"{out}: no unfinished scan to resume (no {SCAN_FOLDER}/{PLAN_NAME}); "
                        "start the scan again")
    plan, notes, colorspace = read_plan(Path(out))
    mapping = read_exr_channels(Path(out) / "mapping.exr", ("y", "x"))
    return Scan(out, plan, mapping, notes, colorspace)


def estimated_seconds(planned: PlannedScan, projector: Projector) -> float:
    """The scan's duration: the plan's exposures, the projector's settle time and the camera's
    overhead per capture measured while probing, with the dark frame and projector checks."""
    return planned.plan.estimated_seconds(planned.exposure.capture_overhead, projector.settle_time, CHECK_EVERY)


def camera_notes(camera: Camera) -> str:
    return "camera: " + ", ".join(f"{key} {value}" for key, value in camera.properties().items())


def check_same_camera(scan: Scan, camera: Camera) -> None:
    """Refuse to resume ``scan`` with a camera other than the one it began with: one whose
    description (:func:`camera_notes`: model, serial, pixel format, gain, black level; a simulated
    rig's options) differs from the one its plan keeps. A resume on another simulated rig wrote
    frames of two scenes into one dataset, told only by a drift note."""
    current = camera_notes(camera)
    if scan.camera_notes and current != scan.camera_notes:
        raise ScanError(f"{scan.out}: the scan began with another camera or other settings ({scan.camera_notes}); "
                        f"this one is {current.removeprefix('camera: ')}: resume with those")


def run_scan(scan: Scan, camera: Camera, projector: Projector, resume: bool,
             progress: Callable[[ScanProgress], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> Path:
    if resume:
        check_same_camera(scan, camera)
    scan.prepare(resume)
    return scan.run(camera, projector, progress, should_stop)
