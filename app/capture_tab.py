"""The Capture tab's logic: runs each wizard step on the chosen hardware in a worker thread.

The capture pool runs one job at a time, so the camera is never used by two steps at once: the
live view (its own job slot) is stopped before any other step starts and yields to it.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from PySide6.QtCore import QObject, QThreadPool, Signal
from ringlight.core.capture.calibration import calibrate_colour, capture_white, measure_dark
from ringlight.core.capture.hardware import discover_plugins, make_device, open_pair, parse_options
from ringlight.core.capture.live_view import LIVE_FPS, summarise_frame
from ringlight.core.capture.scan import Scan, capture_with_timeout
from ringlight.core.capture.scan_plan import ScanError, estimate_disk
from ringlight.core.dataset.memory import format_bytes
from ringlight.core.optics.table import DEFAULT_PHOTONS
from ringlight.core.capture.workflow import (
    camera_notes,
    estimated_seconds,
    measure_correspondence,
    plan_scan,
    resume_scan,
    run_scan,
)
from ringlight.widgets.capture_wizard import (
    FINISH,
    LIVE_VIEW,
    PLAN,
    REGION,
    SCAN,
    CaptureWizard,
)
from ringlight.widgets.jobs import JobSlot

from .reference_calibration import ReferenceCalibration


class CaptureTab(QObject):
    """Signals: ``dataset_ready(str)`` when a scan finished; ``error(str, str)`` title and message;
    ``live_frame(LiveFrame)`` from the live view's worker (shown by the wizard)."""

    dataset_ready = Signal(str)
    error = Signal(str, str)
    live_frame = Signal(object)

    def __init__(self, wizard: CaptureWizard, pool: QThreadPool, parent: QObject | None = None):
        super().__init__(parent)
        self.wizard = wizard
        self.jobs = JobSlot(pool, self)
        self.live_jobs = JobSlot(pool, self)
        self.calibration_jobs = JobSlot(pool, self)
        self.calibration_photons = DEFAULT_PHOTONS  # the model table's white run (tests use fewer)
        self.discovery = discover_plugins()
        wizard.set_devices(sorted(self.discovery.cameras()), sorted(self.discovery.projectors()),
                           [f"{name}: {reason}" for name, reason in self.discovery.failures])
        self.camera = self.projector = self.correspondence = self.planned = None
        self.dark = self.white = self.colour_fit = None
        self._step = ""
        self._started = 0.0
        self._first_fraction: float | None = None
        self._drift: float | None = None
        self._scan: Scan | None = None
        wizard.open_requested.connect(self.open_devices)
        wizard.live_requested.connect(self.start_live)
        wizard.live_stop_requested.connect(self.live_jobs.cancel)
        wizard.dark_requested.connect(self.measure_dark)
        wizard.chart_requested.connect(self.capture_chart)
        wizard.colour_fit_requested.connect(self.fit_colour)
        self.live_frame.connect(wizard.live_page.show_frame)
        self.live_jobs.started.connect(lambda _: wizard.live_page.set_running(True))
        self.live_jobs.idle.connect(lambda: wizard.live_page.set_running(False))
        self.live_jobs.failed.connect(lambda message: self.error.emit("Live view", message))
        wizard.correspondence_requested.connect(self.measure)
        wizard.probe_requested.connect(self.probe)
        wizard.scan_requested.connect(self.scan)
        wizard.pause_requested.connect(self.jobs.cancel)
        wizard.open_dataset_requested.connect(self.dataset_ready)
        self.jobs.finished.connect(self._on_finished)
        self.jobs.failed.connect(self._on_failed)
        self.jobs.cancelled.connect(self._on_cancelled)
        self.jobs.progress.connect(self._on_progress)
        box = wizard.reference_box
        box.calibrate_requested.connect(self.calibrate_reference)
        self.calibration_jobs.started.connect(lambda _: box.set_busy(True))
        self.calibration_jobs.idle.connect(lambda: box.set_busy(False))
        self.calibration_jobs.finished.connect(lambda result: box.set_status(result.summary()))
        self.calibration_jobs.failed.connect(self._on_calibration_failed)

    def open_devices(self, camera_name: str, projector_name: str, options_text: str,
                     camera_options_text: str = "") -> None:
        """Open the devices with ``options_text`` (both) and ``camera_options_text`` (the camera's
        own, e.g. a pylon camera's serial), each "KEY=VALUE" separated by spaces."""
        if self.live_jobs.busy:  # its worker may be inside a capture: never close a camera under it
            self.error.emit("Capture", "Stop the live view (step 2) before opening devices.")
            return
        self.close_devices()

        def work(progress):
            options = parse_options(options_text.split())
            camera_options = {**options, **parse_options(camera_options_text.split())}
            camera = make_device(self.discovery.cameras(), camera_name, camera_options, progress)
            projector = make_device(self.discovery.projectors(), projector_name, options, progress)
            open_pair(camera, projector)  # a simulated rig is made here, its progress shown
            return camera, projector
        self._start("devices", f"Opening {camera_name} and {projector_name}", work)

    def start_live(self, exposure: float) -> None:
        """Stream frames at ``exposure`` seconds, about LIVE_FPS a second, until stopped."""
        if not self._require_devices():
            return
        if self.jobs.busy:
            self.error.emit("Live view", "Another step is using the camera; start the live view when it ends.")
            return
        camera = self.camera

        def work(progress):
            while True:
                started = time.monotonic()
                frame = capture_with_timeout(camera, exposure)
                self.live_frame.emit(summarise_frame(frame, camera.black_level, camera.saturation_level, exposure))
                progress(0.0)  # raises Cancelled once stopped
                while time.monotonic() - started < 1 / LIVE_FPS:
                    time.sleep(0.02)
                    progress(0.0)
        self.live_jobs.start("Live view", work)

    def measure_dark(self, exposure: float, frames: int) -> None:
        if self._require_devices():
            camera, projector = self.camera, self.projector
            self._start("dark", f"Averaging {frames} dark frames",
                        lambda progress: measure_dark(camera, projector, exposure, frames, progress))

    def capture_chart(self) -> None:
        if self._require_devices():
            camera, projector = self.camera, self.projector
            self._start("chart", "Capturing the chart under white", lambda progress: capture_white(camera, projector))

    def fit_colour(self, corners: list) -> None:
        if self.white is None:
            self.error.emit("Capture", "Capture the chart first (step 4, Colour: Capture chart).")
            return
        white = self.white
        self._start("colour", "Fitting the colour matrix", lambda progress: calibrate_colour(white, corners))

    def measure(self) -> None:
        if self._require_devices():
            camera, projector = self.camera, self.projector
            self._start("correspondence", "Gray code correspondence",
                        lambda progress: measure_correspondence(camera, projector, progress))

    def probe(self, roi: tuple, max_radius: float) -> None:
        if self._require_devices() and self.correspondence is not None:
            camera, projector, correspondence = self.camera, self.projector, self.correspondence
            self._start("probe", "Probing exposures",
                        lambda progress: plan_scan(camera, projector, correspondence, roi, max_radius))
        elif self.correspondence is None:
            self.error.emit("Capture", "Measure the correspondence first (step 5, Correspondence).")

    def scan(self, out: str, resume: bool) -> None:
        if not self._require_devices():
            return
        if not out:
            self.error.emit("Capture", "Choose an output folder (step 7, Plan).")
            return
        try:
            if resume:
                scan = resume_scan(out)
            elif self.planned is None:
                raise ScanError("probe exposures first (step 6, Region and exposure)")
            else:
                needed, free = estimate_disk(self.planned.plan, self.planned.mapping.shape[:2], Path(out))
                if needed > free:
                    raise ScanError(f"{out}: the scan needs about {format_bytes(needed)}, {format_bytes(free)} free")
                plan = dataclasses.replace(self.planned.plan, multiplex=self.wizard.multiplex_order())
                colorspace = self.colour_fit.colorspace() if self.colour_fit is not None else "sRGB"
                scan = Scan(out, plan, self.planned.mapping, camera_notes(self.camera), colorspace)
        except ScanError as problem:
            self.error.emit("Capture", str(problem))
            return
        camera, projector = self.camera, self.projector
        self._started = time.monotonic()
        self._first_fraction = None
        self._drift = None
        self._scan = scan
        self.wizard.go_to(SCAN)
        self.wizard.set_scan_state("running")

        def work(progress):
            def report(state):
                self._drift = state.drift  # read by _on_progress in the GUI thread
                progress(state.done / state.total)
            return run_scan(scan, camera, projector, resume, report)
        self._start("scan", f"Scanning {len(scan.frames)} frames", work)

    def calibrate_reference(self, scan: str, mua, musp, n, description: str, out: str) -> None:
        """Calibrate the rig on the reference's scan and write the calibration file, in a worker."""
        request = ReferenceCalibration(scan, tuple(mua), tuple(musp), n, description, out, self.calibration_photons)
        self.calibration_jobs.start(f"Calibrating on {Path(scan).name}", request.run)

    def _on_calibration_failed(self, message: str) -> None:
        self.wizard.reference_box.set_status(f"Failed: {message.splitlines()[0]}")
        self.error.emit("Calibration", message)

    def close_devices(self) -> None:
        for device in (self.camera, self.projector):
            if device is not None:
                device.close()
        self.camera = self.projector = self.correspondence = self.planned = None
        self.dark = self.white = self.colour_fit = None

    def shutdown(self) -> None:
        self.calibration_jobs.close()
        self.live_jobs.close()
        self.jobs.close()

    def _require_devices(self) -> bool:
        if self.camera is None or self.projector is None:
            self.error.emit("Capture", "Open the devices first (step 1).")
            return False
        return True

    def _start(self, step: str, description: str, work) -> None:
        self.live_jobs.cancel()  # the pool runs one job: the live view yields the camera
        self._step = step
        self.jobs.start(description, work)

    def _on_progress(self, fraction: float) -> None:
        if self._step == "scan":
            # A resumed scan starts part-way: the rate counts only this run's frames.
            if self._first_fraction is None:
                self._first_fraction, self._started = fraction, time.monotonic()
            elapsed = time.monotonic() - self._started
            gained = fraction - self._first_fraction
            left = f"about {elapsed * (1 - fraction) / gained:.0f} s left" if gained > 0 else "estimating time left"
            self.wizard.set_scan_progress(fraction, f"{fraction:.0%} done, {elapsed:.0f} s elapsed, {left}")
            if self._drift is not None:
                self.wizard.drift_label.setText(f"Projector check: the lit impulse's radiance is {self._drift:+.2%} "
                                                "from the first check.")

    def _on_finished(self, result) -> None:
        wizard = self.wizard
        if self._step == "devices":
            self.camera, self.projector = result
            height, width = self.projector.size
            wizard.set_roi((0, 0, height, width))
            wizard.devices_label.setText(
                f"Camera {self.camera.frame_shape[1]} x {self.camera.frame_shape[0]}, exposures "
                f"{self.camera.exposure_range[0]:g}..{self.camera.exposure_range[1]:g} s, saturation "
                f"{self.camera.saturation_level:g}; projector {width} x {height}.")
            wizard.go_to(LIVE_VIEW)
        elif self._step == "dark":
            self.dark = result
            wizard.dark_page.show_dark(result)
        elif self._step == "chart":
            self.white = result
            wizard.colour_page.show_chart(result.radiance)
        elif self._step == "colour":
            self.colour_fit = result
            wizard.colour_page.show_fit(result)
        elif self._step == "correspondence":
            self.correspondence = result
            height, width = self.projector.size
            wizard.show_mapping(result.mapping((0, 0, height, width)))
            wizard.show_projector_view(result.projector_view((height, width)))
            wizard.correspondence_label.setText(
                f"{result.inliers} camera pixels fit the homography (residual {result.residual_rms:.2f} "
                f"projector pixels rms); {int(result.lit.sum())} camera pixels see projector light. "
                f"Next: step {REGION + 1}.")
        elif self._step == "probe":
            self.planned = result
            plan = result.plan
            needed, free = estimate_disk(plan, result.mapping.shape[:2], Path(wizard.out_edit.text() or "."))
            grid = plan.grid_shape
            wizard.plan_label.setText(
                f"{grid[0]} x {grid[1]} grid, lattice spacing {plan.spacing}: {len(plan.frames())} frames instead of "
                f"{grid[0] * grid[1]}. Exposures {', '.join(f'{e:.3g}' for e in plan.exposures)} s. About "
                f"{estimated_seconds(result, self.projector):.0f} s (measured {result.exposure.capture_overhead * 1000:.0f} ms "
                f"per capture beyond its exposure) and {format_bytes(needed)} "
                f"({format_bytes(free)} free).")
            wizard.probe_label.setText(
                f"Brightest impulse {result.exposure.peak_rate:.3g} counts/s, faint light {result.exposure.faint_rate:.3g} "
                f"counts/s: {len(plan.exposures)} brackets.")
            wizard.go_to(PLAN)
        elif self._step == "scan":
            wizard.set_scan_state("idle")
            wizard.set_scan_progress(1.0, f"Finished: {result}")
            wizard.drift_label.setText(self._scan.projector_check.summary() or "No projector checks in this scan.")
            wizard.finish_label.setText(f"Dataset written to {result}.")
            wizard.open_dataset_button.setEnabled(True)
            wizard.reference_box.set_scan(str(result))
            wizard.go_to(FINISH)

    def _on_failed(self, message: str) -> None:
        if self._step == "scan":
            self.wizard.set_scan_state("paused")
            self.wizard.set_scan_progress(self.wizard.scan_bar.value() / 1000, message.splitlines()[0])
        self.error.emit("Capture", message)

    def _on_cancelled(self) -> None:
        if self._step == "scan":
            self.wizard.set_scan_state("paused")
            self.wizard.set_scan_progress(self.wizard.scan_bar.value() / 1000,
                                          "Paused: every captured frame is kept. Press Resume to continue.")
