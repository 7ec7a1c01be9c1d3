"""Opening datasets in the explorer: the dialog, drops, samples, and applying an opened dataset.

A mixin of :class:`ringlight.app.window.MainWindow`; the opening itself (manifest, store, stacks)
runs in the load worker through :func:`.session.load_for_viewing`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QFileDialog
from ringlight.core.colour.first_view import FirstView
from ringlight.core.rings.stacks import kernels_compiled
from ringlight.core.simulate.samples import DEMO_SAMPLE, sample_folder
from ringlight.core.simulate.transport import simulated_before_camera_measure

from .help_dialogs import EXITANCE_NOTICE
from .session import LoadedDataset, load_for_viewing

FIRST_VIEW_MESSAGE_MS = 60_000
"""How long the first view's line stays in the status bar (unless another replaces it)."""
DATASET_NAME_PX = 200
"""Width the dataset's name may take in the status bar; a longer one is elided in its middle."""
EMPTY_HINT = "No dataset open: File > Open (Ctrl+O), drop a dataset folder here, or File > Open demo dataset"
FIRST_START = ("This first start after an install or update compiles ringlight's numerical kernels, once: "
               "about half a minute on two cores.")
"""Said under an empty view's "Opening ..." while numba's cache is empty (a fresh install, or sources
changed since the kernels were compiled: :mod:`ringlight.core.kernel_cache`)."""


class DatasetOpening:
    """File > Open, Open sample, Open recent's target, drops, and the window's state on an open
    (mixed into MainWindow)."""

    def choose_dataset(self) -> None:
        start = self.settings.value("last_folder", str(Path.home()))
        folder = QFileDialog.getExistingDirectory(self, "Open impulse dataset", start)
        if folder:
            self.open_dataset(folder)

    def open_dataset(self, path: str | Path | None) -> None:
        """Open ``path`` (None: the demo dataset) in a worker; the current dataset stays until
        the new one is ready, and stays on failure."""
        if path is None:
            self._start_open("Opening the demo dataset", None, DEMO_SAMPLE)
        else:
            self._start_open(f"Opening {Path(path).name}", path, None)

    def open_sample(self, name: str) -> None:
        """Open the bundled sample ``name`` (written into the user cache the first time)."""
        self._start_open(f"Opening the {name} sample", None, name)

    def _start_open(self, description: str, path: str | Path | None, sample: str | None) -> None:
        """Open ``path``, or the bundled ``sample``, with the stack last shown for it."""
        request = self.saved_request(sample_folder(sample) if path is None else path)
        self._pending_request = None
        self.stack_jobs.cancel()
        self.fit_jobs.cancel()
        if self.loaded is None:  # an empty view says what is coming (the status bar says how far)
            self.image_panel.clear_image()
            self.image_panel.set_title(f"{description} ..." + ("" if kernels_compiled() else "\n" + FIRST_START))
        device = self.compute_device()
        self.load_jobs.start(description, lambda progress: load_for_viewing(
            path, request, progress, sample=sample, preview=self.steady_previewed.emit, device=device))

    def _on_open_cancelled(self) -> None:
        self._open_cancelled = True

    def _hint_when_empty(self) -> None:
        """With no dataset shown (first start, an open cancelled or failed), say how to get one;
        after a cancelled open, say so (and that the dataset on screen, if any, stays)."""
        cancelled, self._open_cancelled = self._open_cancelled, False
        if self.loaded is None:
            self.image_panel.clear_image()  # a steady-state preview of an open that did not finish
            self.image_panel.set_title(EMPTY_HINT)
            self.statusBar().showMessage(("Opening cancelled; nothing of it was kept. " if cancelled else "")
                                         + EMPTY_HINT)
        elif cancelled:
            self.statusBar().showMessage(f"Opening cancelled; {self.loaded.dataset.path.name} stays open", 10000)

    def _open_captured(self, path: str) -> None:
        self.main_tabs.setCurrentIndex(0)
        self.open_dataset(path)

    def _on_loaded(self, loaded: LoadedDataset) -> None:
        another = self.loaded is None or self.loaded.dataset.path != loaded.dataset.path
        if self.loaded is not None:
            self._remember_request()
        self.loaded = loaded
        self._impulse_cache = None
        self._forget_levels()
        dataset = loaded.dataset
        self.stack_controls.set_request(loaded.stacks.pair.request, dataset.max_radius)
        if loaded.truth is not None and self.truth_panel.isHidden():
            self.truth_panel.show()
            self.splitter.setSizes([1, 1])  # T_r and its truth side by side at one scale (any extra split alike)
        self.truth_panel.setVisible(loaded.truth is not None)
        height, width = dataset.grid_shape
        self.image_panel.set_scale_bar(dataset.manifest.pitch_mm, width)
        self._apply_radius_unit()
        first = loaded.first_view if another and self.structure_view_action.isChecked() else None
        saved = self.saved_view(dataset.path) if another and first is None else None
        if first is not None:
            self.picked = first.pick  # on the structure the first view found
            if self.display_settings().normalisation in ("per-image", "range"):  # not a choice of the user's
                self.display_controls.set_settings(self.display_settings().with_changes(
                    normalisation=first.normalisation))
        elif saved is not None and saved[1][0] < height and saved[1][1] < width:
            self.picked = saved[1]  # where it was left
        elif another or self.picked is None or not (self.picked[0] < height and self.picked[1] < width):
            self.picked = (height // 2, width // 2)  # a new dataset starts at its centre
        if another:
            self._hovered = None
            self.hover_label.clear()
        self._install_stacks(loaded.stacks)
        if first is not None:
            self.scrub_bar.set_index(first.radius_index)
            if not first.structured:  # a layered material: its structure is in depth, the layer colours
                self.analysis_tabs.setCurrentWidget(self.layer_panel)
        elif saved is not None:
            self.set_radius(saved[0])
        pending, self._pending_request = self._pending_request, None
        if pending is not None and pending != loaded.stacks.pair.request:  # edited while it opened
            self.stack_controls.set_request(pending, dataset.max_radius)
            self.request_stacks(self.stack_controls.request())
        self._remember_recent(dataset.path)
        self.settings.setValue("last_folder", str(dataset.path.parent))
        self._update_title()
        if loaded.notice is not None:
            self.statusBar().showMessage(loaded.notice, 15000)
        elif first is not None:
            self.statusBar().showMessage(first_view_line(first, float(self.stacks.pair.radii[first.radius_index])),
                                         FIRST_VIEW_MESSAGE_MS)
        if simulated_before_camera_measure(dataset.manifest):
            self._information("Simulated before camera radiance", EXITANCE_NOTICE.format(path=dataset.path))
        self.dataset_loaded.emit()

    def _apply_radius_unit(self) -> None:
        """Profiles' radius axis in mm where View > Radius in mm is checked and the dataset's
        pitch is known (the action is disabled where it is not), else in grid steps."""
        pitch_mm = self.loaded.dataset.manifest.pitch_mm if self.loaded is not None else None
        self.radius_mm_action.setEnabled(bool(pitch_mm))
        self.profile_plot.set_radius_unit(pitch_mm if self.radius_mm_action.isChecked() else None)

    def _update_title(self) -> None:
        if self.loaded is None:
            self.setWindowTitle("ringlight")
            return
        dataset = self.loaded.dataset
        manifest = dataset.manifest
        height, width = dataset.grid_shape
        radii = self.stacks.pair.radii if self.stacks else np.zeros(1)
        self.setWindowTitle(f"{dataset.path.name} - ringlight")
        # Short in the status bar (beside the hover readout, at 1366 px), the whole line in its tooltip.
        name = self.dataset_label.fontMetrics().elidedText(dataset.path.name, Qt.TextElideMode.ElideMiddle,
                                                           DATASET_NAME_PX)
        self.dataset_label.setText(f"{name}: {width}x{height}, r {radii[0]:g}..{radii[-1]:g}"
                                   + ("" if dataset.in_memory else ", out of core"))
        self.dataset_label.setToolTip(
            f"{dataset.path}: grid {width}x{height}, {len(manifest.frames)} frames, "
            f"{dataset.missing_count} missing, max_radius {dataset.max_radius:g}, "
            f"r {radii[0]:g}..{radii[-1]:g}" + ("" if dataset.in_memory else ", read from its store (out of core)")
        )

    def dragEnterEvent(self, event) -> None:
        if _dropped_dataset(event.mimeData()) is not None:
            event.acceptProposedAction()

    def dropEvent(self, event) -> None:
        path = _dropped_dataset(event.mimeData())
        if path is not None:
            event.acceptProposedAction()
            self.open_dataset(path)


def first_view_line(first: FirstView, radius: float) -> str:
    """The status bar's line on a first open: what is shown and what to try."""
    if not first.structured:
        return ("T_r is uniform at every radius (layered?): its structure is in depth, the layer colours "
                "(Analysis > Layers). Try: scrub r, Fit (F)")
    return (f"T_r at r = {radius:g}: its structure stands out most here (contrast "
            f"{first.contrast[first.radius_index]:.0%}, levels min-max). Try: scrub r, click a point, "
            "Analysis > Layers")


def _dropped_dataset(mime) -> Path | None:
    """The dataset folder (or dataset.json) among dropped URLs, if any."""
    if not mime.hasUrls():
        return None
    for url in mime.urls():
        if url.isLocalFile():
            path = Path(url.toLocalFile())
            if path.is_dir() or path.name == "dataset.json":
                return path
    return None
