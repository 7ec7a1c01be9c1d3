"""The explorer's main window: wires the widgets to an opened dataset and its stacks.

State lives here (dataset, stacks, picked point, radius index, display settings); widgets only
show what they are given and report what the user did. Slow work (opening, stacks, their noise,
exports) runs in :class:`JobSlot` workers; their results are applied in the GUI thread.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QSettings, Qt, QThreadPool, Signal
from PySide6.QtWidgets import (
    QDockWidget,
    QLabel,
    QMainWindow,
    QMessageBox,
    QSplitter,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)
from ringlight.core import RinglightError
from ringlight.core.colour.display import warm_up_display
from ringlight.core.rings.profiles import PixelProfile
from ringlight.core.rings.stack_request import StackRequest
from ringlight.core.rings.stacks import kernels_compiled, warm_up_kernels
from ringlight.widgets.capture_wizard import CaptureWizard
from ringlight.widgets.display_controls import DisplayControls
from ringlight.widgets.image_panel import ImagePanel
from ringlight.widgets.job_indicator import JobIndicator
from ringlight.widgets.jobs import JobSlot
from ringlight.widgets.layer_panel import LayerPanel
from ringlight.widgets.levels_histogram import LevelsHistogram
from ringlight.widgets.profile_plot import ProfilePlot
from ringlight.widgets.scrub_bar import ScrubBar
from ringlight.widgets.stack_controls import StackControls
from ringlight.widgets.status_bar import ElidingStatusBar

from .capture_tab import CaptureTab
from .dataset_opening import DatasetOpening
from .explore_view import ExploreView
from .export_actions import ExportActions
from .help_dialogs import HelpDialogs
from .layer_tab import LayerTab
from .noise_view import NoiseView, ViewNoise
from .optics_view import OpticsView
from .session import LoadedDataset, ViewStacks, compute_view_stacks
from .view_levels import ViewLevels
from .window_device import WindowDevice
from .window_menus import WindowMenus
from .window_settings import WindowSettings, first_size
from .window_tools import LineProfileDock

class MainWindow(DatasetOpening, ExploreView, ViewLevels, NoiseView, OpticsView, ExportActions, WindowMenus, WindowSettings,
                 WindowDevice, HelpDialogs, LineProfileDock, QMainWindow):
    """The explorer. ``settings`` holds layout and preferences (a QSettings the caller owns)."""

    dataset_loaded = Signal()
    stacks_ready = Signal()
    image_shown = Signal()
    steady_previewed = Signal(object, int, str)
    """The steady state as far as an open has built it (see :func:`~.session.load_for_viewing`)."""
    error_shown = Signal(str)

    def __init__(self, settings: QSettings, parent: QWidget | None = None):
        super().__init__(parent)
        self.settings = settings
        self.loaded: LoadedDataset | None = None
        self.stacks: ViewStacks | None = None
        self.picked: tuple[int, int] | None = None
        self.profile: PixelProfile | None = None
        self.noise: ViewNoise | None = None
        self._noise_failed_for = None  # the StackPair whose noise estimate failed, if any
        self.last_error = ""
        self._levels: tuple[float, float] = (0.0, 1.0)
        self._levels_cache: dict[tuple, tuple[float, float]] = {}  # levels and histograms of stack images,
        self._histograms: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}  # kept until the stacks change
        self._impulse_cache: tuple[tuple[int, int], np.ndarray] | None = None
        self._shown_image: np.ndarray | None = None
        self._hovered: tuple[int, int] | None = None  # the grid point under the mouse, for the readout
        self._open_cancelled = False  # until the load slot is next idle
        self._pending_request: StackRequest | None = None  # asked for while a dataset opened
        self.truth_correlation = float("nan")

        self.pool = QThreadPool(self)
        self.pool.setMaxThreadCount(1)  # numba kernels: one compute job at a time
        self.export_pool = QThreadPool(self)
        self.export_pool.setMaxThreadCount(1)
        self.load_jobs = JobSlot(self.pool, self)
        self.stack_jobs = JobSlot(self.pool, self)
        self.noise_jobs = JobSlot(self.pool, self)
        self.export_jobs = JobSlot(self.export_pool, self)
        self.fit_jobs = JobSlot(self.pool, self)
        self.impulse_jobs = JobSlot(self.pool, self)
        self._impulse_wanted: tuple[int, int] | None = None
        self.capture_pool = QThreadPool(self)
        self.capture_pool.setMaxThreadCount(1)

        # Numba's one-time set-up holds the GIL for ~0.1 s: pay it now, in the worker, not mid-use.
        self.pool.start(_warm_up)
        self.setStatusBar(ElidingStatusBar(self))
        self._build_widgets()
        self.layer_tab = LayerTab(self.layer_panel, self.image_panel, self.scrub_bar, self.export_jobs,
                                  self.fit_jobs, self)
        self.capture_tab = CaptureTab(self.capture_wizard, self.capture_pool, self)
        self._build_optics()
        self.statusBar().addPermanentWidget(JobIndicator(self.capture_tab.jobs))
        self._build_menus()
        self._connect()
        self._restore_settings()
        self.setAcceptDrops(True)
        self._update_title()

    # ----------------------------------------------------------------- construction
    def _build_widgets(self) -> None:
        self.image_panel = ImagePanel()
        self.truth_panel = ImagePanel("ground truth")
        self.truth_panel.hide()
        self.truth_panel.view.setXLink(self.image_panel.view)  # zoom and pan both together
        self.truth_panel.view.setYLink(self.image_panel.view)
        self.splitter = QSplitter(Qt.Orientation.Horizontal)
        self.splitter.addWidget(self.image_panel)
        self.splitter.addWidget(self.truth_panel)
        for index in range(2):  # a resize grows or shrinks both alike: equal panels stay equal
            self.splitter.setStretchFactor(index, 1)
        self.scrub_bar = ScrubBar()
        central = QWidget()
        layout = QVBoxLayout(central)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addWidget(self.splitter, 1)
        layout.addWidget(self.scrub_bar)
        self.capture_wizard = CaptureWizard()
        self.main_tabs = QTabWidget()
        self.main_tabs.addTab(central, "Explore")
        self.main_tabs.addTab(self.capture_wizard, "Capture")
        self.setCentralWidget(self.main_tabs)

        self.display_controls = DisplayControls()
        self.stack_controls = StackControls()
        self.profile_plot = ProfilePlot()
        self.layer_panel = LayerPanel()
        self.analysis_tabs = QTabWidget()
        self.analysis_tabs.addTab(self.profile_plot, "Profiles")
        self.analysis_tabs.addTab(self.layer_panel, "Layers")
        self.levels_histogram = LevelsHistogram()
        self.levels_histogram.setToolTip("Values of the shown image; drag the region's edges to set manual levels")
        display = QWidget()
        display_layout = QVBoxLayout(display)
        display_layout.setContentsMargins(0, 0, 0, 0)
        display_layout.addWidget(self.display_controls)
        display_layout.addWidget(self.levels_histogram)
        self.display_dock = self._dock("Display", display, Qt.DockWidgetArea.LeftDockWidgetArea)
        self.stack_dock = self._dock("Stack", self.stack_controls, Qt.DockWidgetArea.LeftDockWidgetArea)
        self.profile_dock = self._dock("Analysis", self.analysis_tabs, Qt.DockWidgetArea.RightDockWidgetArea)
        self._build_line_profile()

        self.hover_label = QLabel()
        self.hover_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.statusBar().addWidget(self.hover_label, 1)
        self.region_label = self.layer_panel.region_statistics_label  # beside the region's controls
        for slot in (self.load_jobs, self.stack_jobs, self.noise_jobs, self.fit_jobs, self.export_jobs,
                     self.impulse_jobs):
            self.statusBar().addPermanentWidget(JobIndicator(slot))
        self.dataset_label = QLabel("No dataset")
        self.statusBar().addPermanentWidget(self.dataset_label)
        self.resize(first_size(self))

    def _dock(self, title: str, widget: QWidget, area) -> QDockWidget:
        dock = QDockWidget(title, self)
        dock.setObjectName(f"{title.lower()}-dock")
        dock.setWidget(widget)
        self.addDockWidget(area, dock)
        return dock

    def _connect(self) -> None:
        self.load_jobs.finished.connect(self._on_loaded)
        self.load_jobs.failed.connect(lambda message: self.show_error("Could not open the dataset", message))
        self.load_jobs.cancelled.connect(self._on_open_cancelled)
        # An open superseded by another is cancelled too: what was said of it goes as the next starts.
        self.load_jobs.started.connect(lambda _: self.statusBar().clearMessage())
        self.load_jobs.idle.connect(self._hint_when_empty)
        self.steady_previewed.connect(self.show_steady_preview)
        self.stack_jobs.finished.connect(self._on_stacks_ready)
        self.stack_jobs.failed.connect(self._on_stacks_failed)
        self.stack_jobs.cancelled.connect(self._on_stacks_cancelled)
        self.noise_jobs.finished.connect(self._on_noise_ready)
        self.noise_jobs.failed.connect(self._on_noise_failed)
        self.impulse_jobs.finished.connect(self._on_impulse_ready)
        self.impulse_jobs.failed.connect(lambda message: self.show_error("Could not read the impulse image", message))
        for slot in (self.load_jobs, self.stack_jobs):  # new stacks come: free the worker for them
            slot.started.connect(lambda _: self.noise_jobs.cancel())
        self.export_jobs.finished.connect(lambda path: self.statusBar().showMessage(f"Exported {path}", 8000))
        self.export_jobs.failed.connect(lambda message: self.show_error("Export failed", message))
        self.image_panel.pixel_picked.connect(self.pick)
        self.truth_panel.pixel_picked.connect(self.pick)
        self.image_panel.pixel_hovered.connect(self._on_hover)
        self.truth_panel.pixel_hovered.connect(self._on_hover)
        self.scrub_bar.index_changed.connect(self._on_index_changed)
        self.profile_plot.radius_requested.connect(self.set_radius)
        self.display_controls.view_changed.connect(lambda _: self._refresh_all())
        self.display_controls.settings_changed.connect(self._on_display_settings)
        self.display_controls.profile_log_changed.connect(self.profile_plot.set_log_y)
        self.display_controls.denoise_changed.connect(self._on_denoise_changed)
        self.stack_controls.request_changed.connect(self.request_stacks)
        self.layer_panel.export_requested.connect(self.choose_layer_export)
        self.layer_tab.region_changed.connect(self.show_region_statistics)
        self.layer_tab.region_changed.connect(self.refresh_snr_strip)
        self.levels_histogram.levels_dragged.connect(self.set_manual_levels)
        self.capture_tab.error.connect(self.show_error)
        self.capture_tab.dataset_ready.connect(self._open_captured)
        self.analysis_tabs.currentChanged.connect(lambda _: self.layer_tab.on_shown())
        self.profile_dock.visibilityChanged.connect(lambda _: self.layer_tab.on_shown())

    def _fit_layers(self) -> None:
        """F: show the Layers tab with the inverse method and fit the current region."""
        self.analysis_tabs.setCurrentWidget(self.layer_panel)
        self.profile_dock.show()
        self.layer_panel.method_box.setCurrentIndex(self.layer_panel.method_box.findData("inverse"))
        self.layer_tab.fit()

    # ----------------------------------------------------------------- stacks
    def request_stacks(self, request: StackRequest) -> None:
        """Recompute the stacks for ``request`` in a worker; the old ones stay shown meanwhile.
        While a dataset opens, the request waits for it (an edit of the stack controls then was
        overwritten by the open's own request)."""
        if self.load_jobs.busy:
            self._pending_request = request
            return
        if self.loaded is None:
            return
        loaded = self.loaded
        device = self.compute_device()
        self.stack_jobs.start(
            f"Stacks of {len(_safe_radii(request))} radii",
            lambda progress: compute_view_stacks(loaded.dataset, loaded.truth, request, progress, device),
        )

    def _on_stacks_ready(self, stacks: ViewStacks) -> None:
        self._install_stacks(stacks)
        self._update_title()

    def _on_stacks_failed(self, message: str) -> None:
        self.show_error("Could not compute the stack", message)
        self._on_stacks_cancelled()  # the controls show the stack that is on screen, not the refused one

    def _on_stacks_cancelled(self) -> None:
        if self.stacks is not None and self.loaded is not None:
            self.stack_controls.set_request(self.stacks.pair.request, self.loaded.dataset.max_radius)

    def _install_stacks(self, stacks: ViewStacks) -> None:
        self._forget_noise()
        self.stacks = stacks
        self._forget_levels()
        self.scrub_bar.set_radii(stacks.pair.radii)
        self.scrub_bar.set_poor_coverage(stacks.poor_coverage)
        if stacks.coverage_note is not None:
            self.statusBar().showMessage(stacks.coverage_note[0].upper() + stacks.coverage_note[1:], 15000)
        self._refresh_all()
        self.layer_tab.set_data(self.loaded.dataset, stacks.pair.transient)
        self.stacks_ready.emit()

    # ----------------------------------------------------------------- errors, settings, events
    def show_error(self, title: str, message: str) -> None:
        """Show ``message`` (core's one-line error) in a window-modal dialog that does not block."""
        self.last_error = message
        box = QMessageBox(QMessageBox.Icon.Warning, title, message.splitlines()[0], QMessageBox.StandardButton.Ok, self)
        if "\n" in message:
            box.setDetailedText(message)
        box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        line = f"{title}: {message.splitlines()[0]}"
        # The status bar repeats it while the dialog is open, and no longer: it outstayed the
        # dialog by many actions (issue 39).
        box.finished.connect(lambda _: self._clear_message(line))
        box.open()
        self.statusBar().showMessage(line, 10000)
        self.error_shown.emit(message)

    def _clear_message(self, line: str) -> None:
        """Clear the status bar's message if it is still ``line`` (not one shown since)."""
        if self.statusBar().currentMessage() == line:
            self.statusBar().clearMessage()

    def shutdown(self) -> None:
        """Cancel all work, start no more, and wait for the workers (so no job outlives the window)."""
        self.cancel_all()
        for slot in (self.load_jobs, self.stack_jobs, self.noise_jobs, self.fit_jobs, self.export_jobs,
                     self.impulse_jobs, self.optics_jobs, self.optics_region_jobs):
            slot.close()
        self._optics_stop.set()
        self.capture_tab.shutdown()
        self.scrub_bar.timer.stop()
        self.pool.waitForDone()
        self.export_pool.waitForDone()
        self.capture_pool.waitForDone()
        self.capture_tab.close_devices()

    def closeEvent(self, event) -> None:
        if self.export_jobs.busy:
            answer = QMessageBox.question(self, "Export running", "An export is still being written. Cancel it and quit?")
            if answer != QMessageBox.StandardButton.Yes:
                event.ignore()
                return
        self.save_settings()
        self.shutdown()
        super().closeEvent(event)

def _safe_radii(request: StackRequest) -> np.ndarray:
    try:
        return request.radii()
    except RinglightError:
        return np.zeros(0)


def _warm_up() -> None:
    """The compiled kernels of an open, a stack and the image's drawing, loaded in a worker at
    start-up (see :func:`~ringlight.core.rings.stacks.warm_up_kernels`). Not on a fresh install,
    whose first open compiles them side by side with its progress shown
    (:func:`.session.load_for_viewing`): compiled here too, they would be compiled twice at once."""
    if not kernels_compiled():
        return
    warm_up_kernels()
    warm_up_display()
