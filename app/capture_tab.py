"""The Capture tab's logic: runs each wizard step on the chosen hardware in a worker thread."""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import QObject, QThreadPool, Signal
from ringlight.core.capture.hardware import discover_plugins, make_device, parse_options
from ringlight.core.capture.scan import Scan
from ringlight.core.capture.scan_plan import ScanError, estimate_disk, format_bytes
from ringlight.core.capture.workflow import (
    camera_notes,
    measure_correspondence,
    plan_scan,
    resume_scan,
    run_scan,
)
from ringlight.widgets.capture_wizard import CaptureWizard
from ringlight.widgets.jobs import JobSlot


class CaptureTab(QObject):
    """Signals: ``dataset_ready(str)`` when a scan finished; ``error(str, str)`` title and message."""

    dataset_ready = Signal(str)
    error = Signal(str, str)

    def __init__(self, wizard: CaptureWizard, pool: QThreadPool, parent: QObject | None = None):
        super().__init__(parent)
        self.wizard = wizard
        self.jobs = JobSlot(pool, self)
        self.discovery = discover_plugins()
        wizard.set_devices(sorted(self.discovery.cameras()), sorted(self.discovery.projectors()),
                           [f"{name}: {reason}" for name, reason in self.discovery.failures])
        self.camera = self.projector = self.correspondence = self.planned = None
        self._step = ""
        self._started = 0.0
        self._first_fraction: float | None = None
        wizard.open_requested.connect(self.open_devices)
        wizard.correspondence_requested.connect(self.measure)
        wizard.probe_requested.connect(self.probe)
        wizard.scan_requested.connect(self.scan)
        wizard.pause_requested.connect(self.jobs.cancel)
        wizard.open_dataset_requested.connect(self.dataset_ready)
        self.jobs.finished.connect(self._on_finished)
        self.jobs.failed.connect(self._on_failed)
        self.jobs.cancelled.connect(self._on_cancelled)
        self.jobs.progress.connect(self._on_progress)

    def open_devices(self, camera_name: str, projector_name: str, options_text: str) -> None:
        self.close_devices()

        def work(progress):
            options = parse_options(options_text.split())
            camera = make_device(self.discovery.cameras(), camera_name, options)
            projector = make_device(self.discovery.projectors(), projector_name, options)
            camera.open()
            projector.open()
            return camera, projector
        self._start("devices", f"Opening {camera_name} and {projector_name}", work)

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
            self.error.emit("Capture", "Measure the correspondence first (step 2).")

    def scan(self, out: str, resume: bool) -> None:
        if not self._require_devices():
            return
        if not out:
            self.error.emit("Capture", "Choose an output folder (step 4).")
            return
        try:
            if resume:
                scan = resume_scan(out)
            elif self.planned is None:
                raise ScanError("probe exposures first (step 3)")
            else:
                needed, free = estimate_disk(self.planned.plan, self.planned.mapping.shape[:2], Path(out))
                if needed > free:
                    raise ScanError(f"{out}: the scan needs about {format_bytes(needed)}, {format_bytes(free)} free")
                scan = Scan(out, self.planned.plan, self.planned.mapping, camera_notes(self.camera))
        except ScanError as problem:
            self.error.emit("Capture", str(problem))
            return
        camera, projector = self.camera, self.projector
        self._started = time.monotonic()
        self._first_fraction = None
        self.wizard.go_to(4)
        self.wizard.set_scan_state("running")
        self._start("scan", f"Scanning {len(scan.frames)} frames",
                    lambda progress: run_scan(scan, camera, projector, resume,
                                              lambda state: progress(state.done / state.total)))

    def close_devices(self) -> None:
        for device in (self.camera, self.projector):
            if device is not None:
                device.close()
        self.camera = self.projector = self.correspondence = self.planned = None

    def shutdown(self) -> None:
        self.jobs.cancel()

    def _require_devices(self) -> bool:
        if self.camera is None or self.projector is None:
            self.error.emit("Capture", "Open the devices first (step 1).")
            return False
        return True

    def _start(self, step: str, description: str, work) -> None:
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
            wizard.go_to(1)
        elif self._step == "correspondence":
            self.correspondence = result
            height, width = self.projector.size
            wizard.show_mapping(result.mapping((0, 0, height, width)))
            wizard.show_projector_view(result.projector_view((height, width)))
            wizard.correspondence_label.setText(
                f"{result.inliers} camera pixels fit the homography (residual {result.residual_rms:.2f} "
                f"projector pixels rms); {int(result.lit.sum())} camera pixels see projector light. "
                f"Next: step 3.")
        elif self._step == "probe":
            self.planned = result
            plan = result.plan
            needed, free = estimate_disk(plan, result.mapping.shape[:2], Path(wizard.out_edit.text() or "."))
            grid = plan.grid_shape
            wizard.plan_label.setText(
                f"{grid[0]} x {grid[1]} grid, lattice spacing {plan.spacing}: {len(plan.frames())} frames instead of "
                f"{grid[0] * grid[1]}. Exposures {', '.join(f'{e:.3g}' for e in plan.exposures)} s. About "
                f"{plan.estimated_seconds(settle=self.projector.settle_time):.0f} s and {format_bytes(needed)} "
                f"({format_bytes(free)} free).")
            wizard.probe_label.setText(
                f"Brightest impulse {result.exposure.peak_rate:.3g} counts/s, faint light {result.exposure.faint_rate:.3g} "
                f"counts/s: {len(plan.exposures)} brackets.")
            wizard.go_to(3)
        elif self._step == "scan":
            wizard.set_scan_state("idle")
            wizard.set_scan_progress(1.0, f"Finished: {result}")
            wizard.finish_label.setText(f"Dataset written to {result}.")
            wizard.open_dataset_button.setEnabled(True)
            wizard.go_to(5)

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
