"""The Layers tab's logic: region -> trajectory -> picked radii -> recovered layer colours, or, with
the inverse method, region -> fitted layered model.

The paper's methods are cheap (region means of a computed stack and its noise), so they run in
the GUI thread on each change; the inverse method's fit runs in its own worker slot when asked
(Fit, F) and its result stays shown while dataset, region and settings are those it was fitted
for; exports run in the window's export worker. The trusted flags come from the
stack's noise (ring-member spread, :data:`~ringlight.core.colour.layer_report.TRUST_RULE`), which
the window estimates in a worker after each stack: until it arrives the tab shows the trajectory
and waits with the layers.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from PySide6.QtCore import QObject, Signal
from ringlight.core import ImpulseDataset, RinglightError, Stack
from ringlight.core.atomic import atomic_file
from ringlight.core.colour.chroma import colour_unavailable, propose_radii, recover_layers, trajectory
from ringlight.core.colour.image_export import ExportError, write_text
from ringlight.core.colour.layer_report import (
    TRUST_RULE,
    LayerAnalysis,
    analysis_csv,
    analysis_json,
    layer_snr,
    truth_layers,
    with_ring_noise,
)
from ringlight.core.colour.regions import full_region, polygon_region, rectangle_region
from ringlight.core.inversion.settings import settings_from_text
from ringlight.core.inversion.report import DatasetInversion, inversion_json
from ringlight.core.rings.noise import StackNoise
from ringlight.widgets.image_panel import ImagePanel
from ringlight.widgets.jobs import JobSlot
from ringlight.widgets.layer_panel import INVERSE, LayerPanel
from ringlight.widgets.scrub_bar import ScrubBar

from .fit_process import invert_region_apart


PENDING = "Trusted flags: estimating the noise of the stack (status bar)."


class LayerTab(QObject):
    """Keeps the picked radii and the last analysis; ``analysis_changed`` after each update."""

    analysis_changed = Signal()
    region_changed = Signal()

    def __init__(self, panel: LayerPanel, image_panel: ImagePanel, scrub_bar: ScrubBar, exports: JobSlot,
                 fits: JobSlot, parent: QObject | None = None):
        super().__init__(parent)
        self.panel = panel
        self.image_panel = image_panel
        self.scrub_bar = scrub_bar
        self.exports = exports
        self.fits = fits
        self.device = "cpu"
        """Where an inverse fit's white runs go (``--device``'s choices): the window's setting."""
        self.inversion: DatasetInversion | None = None
        self._inversion_key: tuple | None = None
        self.dataset: ImpulseDataset | None = None
        self.stack: Stack | None = None
        self.noise: StackNoise | None = None
        self.picked: list[float] = []
        self.analysis: LayerAnalysis | None = None
        self.region = np.zeros((0, 0), bool)
        self.region_description = "all pixels"
        self._stale = False
        panel.pick_requested.connect(lambda: self.toggle_pick(self.scrub_bar.radius()))
        panel.clear_requested.connect(self.clear_picks)
        panel.auto_requested.connect(self.auto_pick)
        panel.method_changed.connect(lambda _: self.refresh())
        panel.region_mode_changed.connect(image_panel.set_region_mode)
        panel.radius_clicked.connect(self._on_radius_clicked)
        panel.fit_requested.connect(self.fit)
        fits.finished.connect(self._on_fitted)
        fits.failed.connect(lambda message: self.panel.show_message(f"The fit failed: {message}"))
        fits.cancelled.connect(lambda: self.panel.show_message("Fit cancelled."))
        panel.set_trust_rule(TRUST_RULE)
        image_panel.region_changed.connect(self.update_region)

    def set_data(self, dataset: ImpulseDataset, stack: Stack) -> None:
        """Use transient ``stack`` of ``dataset``; picks not among its radii are dropped. Its
        noise is unknown until :meth:`set_noise`."""
        new_dataset = dataset is not self.dataset
        self.dataset, self.stack, self.noise = dataset, stack, None
        if new_dataset:
            self.picked = []
            self.panel.diagram.reset_view()  # the new trajectory may lie outside the old zoom
            self.panel.set_sample(dataset.manifest.sample.n, dataset.manifest.sample.g)  # the fit follows the dataset
        else:
            self.picked = [r for r in self.picked if np.isclose(stack.radii, r).any()]
        if new_dataset or self.region.shape != dataset.grid_shape:
            self.update_region()
        else:
            self.refresh()

    def set_noise(self, noise: StackNoise | None) -> None:
        """Use ``noise`` (of the current stack's radii) for the trusted flags; None: unknown."""
        self.noise = noise
        self.refresh()

    def update_region(self) -> None:
        if self.dataset is None:
            return
        kind, geometry = self.image_panel.region_geometry()
        try:
            if kind == "rectangle":
                y0, x0, y1, x1 = geometry
                self.region = rectangle_region(self.dataset.grid_shape, y0, x0, y1, x1)
                self.region_description = f"rows {y0}..{y1 - 1}, columns {x0}..{x1 - 1}"
            elif kind == "polygon":
                self.region = polygon_region(self.dataset.grid_shape, geometry)
                vertices = ", ".join(f"({y:.1f}, {x:.1f})" for y, x in geometry)
                self.region_description = f"polygon {vertices}"
            else:
                self.region = full_region(self.dataset.grid_shape)
                self.region_description = "all pixels"
        except RinglightError as error:
            self.region = np.zeros(self.dataset.grid_shape, bool)
            self.region_description = "empty"
            self.panel.show_message(str(error))
        self.region_changed.emit()
        self.refresh()

    def toggle_pick(self, radius: float | None) -> None:
        if radius is None or self.stack is None:
            return
        if any(np.isclose(radius, r) for r in self.picked):
            self.picked = [r for r in self.picked if not np.isclose(radius, r)]
        else:
            self.picked = sorted(self.picked + [float(radius)])
        self.refresh()

    def clear_picks(self) -> None:
        self.picked = []
        self.refresh()

    def auto_pick(self, count: int) -> None:
        if self.stack is None:
            return
        if self.noise is None:
            self.panel.show_message(f"Auto picks trusted radii. {PENDING}")
            return
        try:
            self.picked = propose_radii(with_ring_noise(trajectory(self.stack, self.region), self.stack,
                                                        self.noise, self.region), count)
        except RinglightError as error:
            self.panel.show_message(str(error))
            return
        self.refresh()

    def refresh(self) -> None:
        """Recompute the trajectory over the region and, with picks, the layers; while the tab
        is hidden this waits until it is shown (:meth:`on_shown`)."""
        self.analysis = None
        self._stale = not self.panel.isVisible()
        if self.stack is None or self._stale:
            return
        self.panel.set_picked(self.picked)
        if (grey := colour_unavailable(self.dataset.channels)) is not None:
            self.panel.diagram.set_trajectory(np.zeros(0), np.zeros((0, 2)))
            self.panel.show_result(None)
            self.panel.show_message(f"No layer colours: {grey}.")
            self.analysis_changed.emit()
            return
        try:
            path = trajectory(self.stack, self.region)
        except RinglightError as error:
            self.panel.diagram.set_trajectory(np.zeros(0), np.zeros((0, 2)))
            self.panel.show_result(None)
            self.panel.show_message(str(error))
            self.analysis_changed.emit()
            return
        self.panel.diagram.set_trajectory(path.radii, path.xy)
        if self.panel.method() == INVERSE:
            self._show_inversion()
            self.analysis_changed.emit()
            return
        self.panel.set_picked(self.picked)
        if not self.picked:
            self.panel.show_result(None)
            self.panel.show_message(f"Region: {self.region_description}. Pick radii (P, or click the "
                                    f"trajectory) or press Auto.")
            self.analysis_changed.emit()
            return
        # Until the noise is known every SNR is NaN: nothing is trusted, and the table says why.
        path = replace(path, snr=np.full(len(path.radii), np.nan)) if self.noise is None else (
            with_ring_noise(path, self.stack, self.noise, self.region))
        names, truth_rgb = truth_layers(self.dataset)
        try:
            result = recover_layers(path, self.picked, self.panel.method(), truth_rgb)
        except RinglightError as error:
            self.panel.show_result(None)
            self.panel.show_message(str(error))
            self.analysis_changed.emit()
            return
        self.analysis = LayerAnalysis(self.region_description, path, result, names)
        self.panel.show_result(result, names, layer_snr(self.analysis), trust_known=self.noise is not None)
        summary = f"Region: {self.region_description}; method {result.method}."
        if result.errors is not None:
            summary += " Mean xy error " + f"{np.nanmean(result.errors):.4f}."
        # Pending, each layer would warn of its NaN SNR: the warnings return with the noise.
        notes = result.warnings if self.noise is not None else [PENDING]
        self.panel.show_message(" ".join([summary, *notes]))
        self.analysis_changed.emit()

    def _key(self) -> tuple:
        """What an inversion depends on: dataset, region and the settings typed."""
        return (id(self.dataset), self.region_description, self.region.tobytes(),
                tuple(sorted(self.panel.inversion_inputs().items())))

    def _show_inversion(self) -> None:
        current = self.inversion is not None and self._inversion_key == self._key()
        self.panel.show_inversion(self.inversion if current else None)
        if not current:
            self.panel.show_message(f"Region: {self.region_description}. Press Fit (F) to fit a layered model to "
                                    f"the region's ring-light profile (the first fit runs a white Monte Carlo, "
                                    f"about 10-20 s; later ones reuse it).")
            return
        inversion = self.inversion.inversion
        text = (f"Region: {self.region_description}. Chi-square {inversion.chi2:.1f} for {inversion.dof} degrees "
                f"of freedom; {inversion.seconds:.1f} s.")
        if inversion.warning:
            text += f" Warning: {inversion.warning}."
        undetermined = [str(i + 1) for i, layer in enumerate(inversion.layers) if not layer.determined]
        if undetermined and not inversion.warning:
            text += f" Not determined: layer {', '.join(undetermined)} (hover its row for why)."
        self.panel.show_message(text)
        self.panel.message_label.setToolTip(inversion.notes)

    def fit(self) -> None:
        """Fit the layered model to the current region in the worker (the inverse method)."""
        if self.dataset is None or self.panel.method() != INVERSE:
            return
        if (grey := colour_unavailable(self.dataset.channels)) is not None:
            self.panel.show_message(f"No layer colours: {grey}.")
            return
        inputs = self.panel.inversion_inputs()
        try:
            settings = settings_from_text(inputs["layers"], inputs["boundaries"], inputs["mus"], inputs["n"],
                                          inputs["g"], inputs["depth"])
            settings = replace(settings, device=self.device)
        except RinglightError as error:
            self.panel.show_message(str(error))
            return
        dataset, region, description, key = self.dataset, self.region.copy(), self.region_description, self._key()

        def work(progress):  # the fit in a child process: the GUI thread keeps the GIL (fit_process)
            return key, invert_region_apart(dataset, region, description, settings, progress)
        self.panel.show_message("Fitting… (progress in the status bar; Esc cancels)")
        self.fits.start("Fitting layers", work)

    def _on_fitted(self, result) -> None:
        key, inversion = result
        self.inversion, self._inversion_key = inversion, key
        self.refresh()

    def on_shown(self) -> None:
        """The tab became visible: bring it up to date."""
        if self._stale and self.panel.isVisible():
            self.refresh()

    def export(self, kind: str, path: Path) -> None:
        """Write the analysis as ``"json"`` or ``"csv"``, or the diagram as ``"png"``."""
        if kind == "png":
            diagram = self.panel.diagram
            shown = diagram.getPlotItem().vb.viewRange()
            diagram.reset_view()  # the whole diagram, not the user's zoom
            image = diagram.grab().toImage()  # QImage: safe to save off the GUI thread
            diagram.setRange(xRange=shown[0], yRange=shown[1], padding=0)

            def work(progress):
                with atomic_file(path, overwrite=True) as temporary:  # the save dialog asked
                    if not image.save(str(temporary), "PNG"):
                        raise ExportError(f"{path}: could not write the PNG")
                progress(1.0)
                return path
        elif self.panel.method() == INVERSE:
            if self.inversion is None or self._inversion_key != self._key():
                self.panel.show_message("Nothing to export yet: press Fit first.")
                return
            if kind == "csv":
                self.panel.show_message("The inverse method exports JSON (each layer with its two-sigma region).")
                return
            text = inversion_json(self.inversion, str(self.dataset.path))

            def work(progress):
                write_text(path, text, overwrite=True)
                progress(1.0)
                return path
        else:
            if self.analysis is None:
                self.panel.show_message("Nothing to export yet: pick radii first.")
                return
            text = analysis_json(self.analysis, str(self.dataset.path)) if kind == "json" else analysis_csv(self.analysis)

            def work(progress):
                write_text(path, text, overwrite=True)
                progress(1.0)
                return path
        self.exports.start(f"Writing {path.name}", work)

    def _on_radius_clicked(self, radius: float) -> None:
        self.scrub_bar.set_index(self.scrub_bar.nearest_index(radius))
        self.toggle_pick(radius)
