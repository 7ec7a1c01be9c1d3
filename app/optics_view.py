"""Optical-property maps in the explorer: the Optics tab computes mu_a and mu_s' of every pixel
and channel in a worker (:func:`ringlight.core.optics.optical_maps`), shows one map with its
colour bar, the hovered pixel's values with their standard errors and the region's statistics,
and draws the fitted model's E(r) over the measured profile of the picked pixel; Fit region fits
the mean E(r) of the Layers tab's region in a worker of its own
(:func:`ringlight.core.optics.region_optics`), and Cancel stops both.

A mixin of :class:`ringlight.app.window.MainWindow`.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PySide6.QtWidgets import QFileDialog
from ringlight.core import ImpulseDataset
from ringlight.core.device import Device
from ringlight.core.optics import (Calibration, CalibrationError, OpticalMaps, RegionOptics, model_profile,
                                   optical_maps, read_calibration, region_optics)
from ringlight.core.optics.maps import sample_optics
from ringlight.core.optics.radial import radial_run
from ringlight.core.optics.table import DEFAULT_PHOTONS
from ringlight.core.uncertainty_text import with_error, with_errors
from ringlight.widgets.job_indicator import JobIndicator
from ringlight.widgets.jobs import JobSlot
from ringlight.widgets.optics_panel import QUANTITIES, OpticsPanel

UNITS = {"per_mm": "/mm", "per_grid_step": "/grid step"}


def trace_on_device(dataset: ImpulseDataset, n: float | None, g: float | None, photons: int, device: Device | None,
                    progress) -> None:
    """On a CUDA ``device``, trace the table's white run for ``dataset``'s n and g (or those given)
    there, into the user cache where the fits find it (as ``ringlight optics --device``); nothing
    on the CPU, where the fits trace it themselves."""
    if device is not None and device.is_cuda:
        radial_run(*sample_optics(dataset, n, g), photons, progress=progress, device=device)


@dataclass(frozen=True, eq=False)
class OpticsRequest:
    """The maps of ``dataset`` under ``calibration``, with the table's white run of ``photons``, for
    index ``n`` and anisotropy ``g`` (None: the manifest's);
    ``stop`` set asks the fit to stop (its cancel question between pixel blocks). On a CUDA
    ``device`` the table's white run is traced there first, into the user cache where the maps
    find it (as ``ringlight optics --device``); the fits run on the CPU."""

    dataset: ImpulseDataset
    calibration: Calibration | None
    photons: int
    stop: threading.Event
    n: float | None = None
    g: float | None = None
    device: Device | None = None

    def run(self, progress) -> OpticalMaps:
        trace_on_device(self.dataset, self.n, self.g, self.photons, self.device, progress)
        return optical_maps(self.dataset, n=self.n, g=self.g, calibration=self.calibration, progress=progress,
                            cancelled=self.stop.is_set, photons=self.photons)


@dataclass(frozen=True, eq=False)
class RegionRequest:
    """One fit of the mean E(r) of ``mask`` ((H, W) bool; None: the whole grid) of ``dataset``, as
    ``ringlight optics --json`` fits it (:func:`ringlight.core.optics.region_optics`); on a CUDA
    ``device`` the table's white run is traced there first, as :class:`OpticsRequest` does."""

    dataset: ImpulseDataset
    mask: np.ndarray | None
    calibration: Calibration | None
    photons: int
    n: float | None = None
    g: float | None = None
    device: Device | None = None

    def run(self, progress) -> RegionOptics:
        trace_on_device(self.dataset, self.n, self.g, self.photons, self.device, progress)
        return region_optics(self.dataset, self.mask, n=self.n, g=self.g, calibration=self.calibration,
                             photons=self.photons, progress=progress)


def region_fit_text(result: RegionOptics, where: str) -> str:
    """The region fit's values with their standard errors, per channel, its chi-square and the
    channels it did not determine."""
    chi2 = " / ".join(f"{c:.3g}" for c in result.chi2)
    return (f"{where}, fit of its mean E(r) over {result.points} lit points (n {result.n:g}, g {result.g:g}): mu_a "
            f"{with_errors(result.mua, result.mua_se)}, mu_s' {with_errors(result.musp, result.musp_se)} "
            f"{UNITS[result.units]} (R / G / B, ±1 SE); chi2 {chi2} on {len(result.radii) - 2} degrees of "
            f"freedom{result.undetermined_note()}")


def describe_optics(maps: OpticalMaps, y: int, x: int, channel: int) -> str:
    """Both properties of pixel (y, x) in ``channel``, each to the digit its standard error allows,
    and which of them the fit did not determine."""
    unit = UNITS[maps.units]
    parts = []
    for key, name in QUANTITIES.items():
        value = float(getattr(maps, key)[y, x, channel])
        error = float(getattr(maps, f"{key}_se")[y, x, channel])
        if not np.isfinite(value):
            parts.append(f"{name} no fit")
            continue
        text = f"{name} {with_error(value, error if np.isfinite(error) else None)} {unit}"
        if not getattr(maps, f"{key}_determined")[y, x, channel]:
            text += " (not determined)"
        parts.append(text)
    edge = "" if maps.complete[y, x] else "   rings cut by the grid's edge or unlit points (biased)"
    return f"y {y}  x {x}  {maps.channels[channel]}:  " + ",  ".join(parts) + " (±1 SE)" + edge


def region_text(maps: OpticalMaps, key: str, channel: int, region: np.ndarray | None, where: str) -> str:
    """Mean ± standard error of the mean (std / sqrt N) of property ``key`` in ``channel`` over the
    pixels of the (H, W) ``region`` (None: the whole grid) whose value is determined and whose
    rings lie whole on the grid (a cut ring's fit is biased, :attr:`OpticalMaps.complete`), their
    standard deviation, and the median of those pixels' own standard errors: neighbouring pixels'
    fits share ring members, so std / sqrt N understates the mean's error, down to 0 where every
    pixel is alike (a laterally uniform simulation), while each pixel's error says what its data
    allow."""
    values = getattr(maps, key)[..., channel]
    inside = np.ones(values.shape, bool) if region is None else region
    determined = inside & getattr(maps, f"{key}_determined")[..., channel] & np.isfinite(values)
    used = determined & maps.complete
    count, total, cut = int(used.sum()), int(inside.sum()), int((determined & ~maps.complete).sum())
    name, unit = QUANTITIES[key], UNITS[maps.units]
    left_out = f" ({cut} more with rings cut by the edge left out)" if cut else ""
    if count == 0:
        return f"{where}: no pixel of {total} has a determined {name} from whole rings{left_out}"
    chosen = values[used].astype(np.float64)
    std = float(chosen.std(ddof=1)) if count > 1 else float("nan")
    se = std / np.sqrt(count) if count > 1 else None
    pixel_se = float(np.median(getattr(maps, f"{key}_se")[..., channel][used]))
    return (f"{where}: {count} of {total} px{left_out}; {name} {maps.channels[channel]} mean "
            f"{with_error(float(chosen.mean()), se)} {unit} (std / √N), std {std:.3g}, each pixel's SE "
            f"{pixel_se:.2g} (median)")


class OpticsView:
    """The Optics tab's worker, map, readouts and model overlay (mixed into MainWindow)."""

    def _build_optics(self) -> None:
        self.optics: OpticalMaps | None = None
        self.optics_calibration: Calibration | None = None
        self.optics_photons = DEFAULT_PHOTONS  # the model table's white run (tests use fewer)
        self._optics_photons_used = DEFAULT_PHOTONS  # that of the maps on screen
        self._optics_dataset: ImpulseDataset | None = None  # whose maps they are
        self._optics_hovered = (-1, -1)  # the map's pixel under the mouse, for the readout
        self._optics_stop = threading.Event()
        self.optics_panel = OpticsPanel()
        self.analysis_tabs.addTab(self.optics_panel, "Optics")
        self.optics_jobs = JobSlot(self.pool, self)
        self.statusBar().addPermanentWidget(JobIndicator(self.optics_jobs))
        panel = self.optics_panel
        panel.compute_requested.connect(self.compute_optics)
        panel.export_requested.connect(self.choose_optics_export)
        panel.cancel_requested.connect(self.cancel_optics)
        panel.calibration_requested.connect(self.choose_calibration)
        panel.calibration_cleared.connect(lambda: self.set_calibration(None))
        panel.choice_changed.connect(self._refresh_optics)
        panel.pixel_picked.connect(self.pick)
        panel.pixel_hovered.connect(self._on_optics_hover)
        # The region fit: a slot of its own, so that it neither cancels nor is cancelled by the maps.
        self.optics_region_jobs = JobSlot(self.pool, self)
        self.statusBar().addPermanentWidget(JobIndicator(self.optics_region_jobs))
        for slot in (self.optics_jobs, self.optics_region_jobs):
            slot.started.connect(lambda _: self._show_optics_busy())
            slot.idle.connect(self._show_optics_busy)
            slot.progress.connect(panel.set_progress)
        self.optics_jobs.finished.connect(self._on_optics_ready)
        self.optics_jobs.failed.connect(lambda message: self.show_error("Could not compute the optical maps", message))
        self.optics_jobs.cancelled.connect(lambda: panel.set_map(None, title="Cancelled: Compute maps to start again"))
        self.dataset_loaded.connect(self._forget_optics)
        self.layer_tab.region_changed.connect(self._refresh_optics_region)
        panel.fit_region_requested.connect(self.fit_optics_region)
        self.optics_region_jobs.finished.connect(lambda result: panel.set_region_fit(region_fit_text(*result)))
        self.optics_region_jobs.failed.connect(self._on_region_fit_failed)
        self.optics_region_jobs.cancelled.connect(lambda: panel.set_region_fit(""))
        self.layer_tab.region_changed.connect(self._forget_region_fit)

    def _show_optics_busy(self) -> None:
        """Cancel offered while the maps or the region fit run; the progress bar from 0."""
        self.optics_panel.set_busy(self.optics_jobs.busy or self.optics_region_jobs.busy)

    def _show_optics(self) -> None:
        self.analysis_tabs.setCurrentWidget(self.optics_panel)
        self.profile_dock.show()

    def compute_optics(self) -> None:
        """Fit the maps of the dataset on screen in a worker (cancel: :meth:`cancel_optics`)."""
        if self.loaded is None:
            self.optics_panel.set_map(None, title="Open a dataset first")
            return
        if (sample := self._typed_sample("Could not compute the optical maps")) is None:
            return
        n, g = sample
        self._optics_stop.set()  # a job still running stops at its next question
        self._optics_stop = threading.Event()
        request = OpticsRequest(self.loaded.dataset, self.optics_calibration, self.optics_photons, self._optics_stop,
                                n, g, self.compute_device())
        # Started first: starting cancels a job running there, whose cancel would replace the title.
        self.optics_jobs.start("Optical maps", lambda progress: (request, request.run(progress)))
        self.optics = None  # maps of other settings are neither shown, read on hover nor exported
        self._refresh_optics()
        self.profile_plot.set_model(None)
        self.optics_panel.set_map(None, title="Fitting mu_a and mu_s' of every pixel ...")

    def _typed_sample(self, title: str) -> tuple[float | None, float | None] | None:
        """The n and g typed on the tab (None where empty); None after a dialog titled ``title``
        naming the one that is not a number."""
        try:
            return self.optics_panel.sample()
        except ValueError as error:
            self.show_error(title, str(error))
            return None

    def fit_optics_region(self) -> None:
        """Fit the mean E(r) of the Layers tab's region (the whole grid when it holds every pixel)
        in a worker; the result replaces the panel's region-fit line."""
        if self.loaded is None:
            self.optics_panel.set_region_fit("Open a dataset first")
            return
        if (sample := self._typed_sample("Could not fit the region")) is None:
            return
        n, g = sample
        mask, where = self._optics_region(self.loaded.dataset.grid_shape)
        request = RegionRequest(self.loaded.dataset, None if mask is None else mask.copy(), self.optics_calibration,
                                self.optics_photons, n, g, self.compute_device())
        # Started first: starting cancels a fit running there, whose cancel clears the line.
        self.optics_region_jobs.start("Region fit", lambda progress: (request.run(progress), where))
        self.optics_panel.set_region_fit(f"{where}: fitting its mean E(r) ...")

    def _on_region_fit_failed(self, message: str) -> None:
        self.optics_panel.set_region_fit("")
        self.show_error("Could not fit the region", message)

    def _forget_region_fit(self) -> None:
        """A region fit of another region, dataset or calibration is no longer shown."""
        self.optics_region_jobs.cancel()
        self.optics_panel.set_region_fit("")

    def cancel_optics(self) -> None:
        self._optics_stop.set()
        self.optics_jobs.cancel()
        self.optics_region_jobs.cancel()

    def choose_calibration(self) -> None:
        start = self.settings.value("last_calibration_folder", str(Path.home()))
        path, _ = QFileDialog.getOpenFileName(self, "Calibration file", start, "Calibration (*.json);;All files (*)")
        if path:
            self.settings.setValue("last_calibration_folder", str(Path(path).parent))
            self.load_calibration(path)

    def load_calibration(self, path) -> bool:
        """Use the calibration in ``path`` for the next maps; a dialog with one line naming the file
        when it is not one (the calibration in use stays)."""
        try:
            calibration = read_calibration(path)
        except CalibrationError as error:
            self.show_error("Could not read the calibration", str(error))
            return False
        self.set_calibration(calibration, Path(path).name)
        return True

    def set_calibration(self, calibration: Calibration | None, name: str = "") -> None:
        """Use ``calibration`` (None: none); maps fitted under another are dropped."""
        self.optics_calibration = calibration
        if calibration is None:
            self.optics_panel.set_calibration("none (absolute, simulated data)")
        else:
            scale = " ".join(f"{s:.4g}" for s in calibration.scale)
            self.optics_panel.set_calibration(f"{name}, scale R G B {scale}")
        self._forget_optics()

    def _forget_optics(self) -> None:
        self.cancel_optics()
        self.optics_panel.set_region_fit("")
        self.optics = None
        self._refresh_optics()
        self.profile_plot.set_model(None)

    def _on_optics_ready(self, result: tuple[OpticsRequest, OpticalMaps]) -> None:
        request, maps = result
        if self.loaded is None or request.dataset is not self.loaded.dataset:
            return  # another dataset opened meanwhile
        self.optics, self._optics_photons_used, self._optics_dataset = maps, request.photons, request.dataset
        self._refresh_optics()
        self._refresh_optics_model()

    def _refresh_optics(self) -> None:
        """The chosen map, its hover readout and region statistics, again."""
        maps, panel = self.optics, self.optics_panel
        if maps is None:
            if not self.optics_jobs.busy:
                panel.set_map(None)
            panel.set_hover("")
            panel.set_region("")
            return
        key, channel = panel.quantity(), panel.channel()
        name, unit = QUANTITIES[key], UNITS[maps.units]
        calibrated = "calibrated" if self.optics_calibration is not None else "no calibration"
        panel.set_map(getattr(maps, key)[..., channel], getattr(maps, f"{key}_determined")[..., channel],
                      f"{name} ({unit})", f"{name} {maps.channels[channel]}  n {maps.n:g}  g {maps.g:g}  {calibrated}\n"
                      f"dim: not determined, or rings cut (edge, unlit points); grey: no fit", whole=maps.complete)
        if self.picked is not None:
            panel.show_point(*self.picked)
        self._on_optics_hover(*self._optics_hovered)  # the other channel's numbers under the mouse
        self._refresh_optics_region()

    def _refresh_optics_region(self) -> None:
        if self.optics is None:
            return
        mask, where = self._optics_region(self.optics.mua.shape[:2])
        self.optics_panel.set_region(region_text(self.optics, self.optics_panel.quantity(),
                                                 self.optics_panel.channel(), mask, where))

    def _optics_region(self, shape: tuple[int, int]) -> tuple[np.ndarray | None, str]:
        """The Layers tab's region as a (H, W) mask of a grid of ``shape`` and its name; (None,
        "whole grid") when it holds every pixel or belongs to another grid."""
        region = self.layer_tab.region
        if region.shape != shape or region.all():
            return None, "whole grid"
        return region, "Layers region"

    def _on_optics_hover(self, y: int, x: int) -> None:
        self._optics_hovered = (y, x)
        inside = self.optics is not None and 0 <= y < self.optics.mua.shape[0] and 0 <= x < self.optics.mua.shape[1]
        self.optics_panel.set_hover(describe_optics(self.optics, y, x, self.optics_panel.channel()) if inside else "")

    def _refresh_optics_model(self) -> None:
        """The fitted model's E(r) at the picked pixel over its measured profile (each channel
        with its own mu_a, mu_s' and scale); nothing without maps or where the fit failed."""
        maps = self.optics
        loaded = self.loaded
        if maps is None or self.picked is None or loaded is None or self._optics_dataset is not loaded.dataset:
            self.profile_plot.set_model(None)
            return
        y, x = self.picked
        model = np.full((len(maps.radii), 3), np.nan)
        for channel in range(3):
            mua, musp = float(maps.mua[y, x, channel]), float(maps.musp[y, x, channel])
            if np.isfinite(mua) and np.isfinite(musp):
                model[:, channel] = model_profile(mua, musp, maps.radii, n=maps.n, g=maps.g, pitch_mm=maps.pitch_mm,
                                                  scale=float(maps.scale[channel]), photons=self._optics_photons_used)
        self.profile_plot.set_model(maps.radii, model)
        self.profile_plot.set_point(f"at y {y} x {x}\ndashed: mu_a, mu_s' fit")
        self.optics_panel.show_point(y, x)
