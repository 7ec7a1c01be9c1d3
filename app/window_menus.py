"""The explorer's menu bar: File, View, Settings and Help, each action with its shortcut and status tip.

A mixin of :class:`ringlight.app.window.MainWindow`: the actions call the window's own methods
and widgets, which exist when ``_build_menus`` runs.
"""

from __future__ import annotations

from PySide6.QtGui import QAction, QKeySequence
from ringlight.core.simulate.presets import preset_notes
from ringlight.core.simulate.samples import sample_names
from ringlight.widgets.display_controls import VIEWS


class WindowMenus:
    """The menu bar (mixed into MainWindow)."""

    def _action(self, menu, text: str, slot, shortcut=None, tip: str = "") -> QAction:
        action = QAction(text, self)
        if shortcut is not None:
            action.setShortcut(QKeySequence(shortcut))
        action.setStatusTip(tip)
        action.triggered.connect(slot)
        menu.addAction(action)
        return action

    def _build_menus(self) -> None:
        file_menu = self.menuBar().addMenu("&File")
        self._action(file_menu, "&Open dataset…", self.choose_dataset, QKeySequence.StandardKey.Open,
                     "Open an impulse dataset folder or its dataset.json")
        self.recent_menu = file_menu.addMenu("Open &recent")
        self._action(file_menu, "Open &demo dataset", lambda: self.open_dataset(None))
        samples = file_menu.addMenu("Open &sample")
        for name in sample_names():
            self._action(samples, name, lambda _=False, name=name: self.open_sample(name),
                         tip=f"The bundled {name} sample ({preset_notes(name)})")
        file_menu.addSeparator()
        self.export_actions = [
            self._action(file_menu, "Export stack as &EXR…", self.choose_stack_export, "Ctrl+E",
                         "The shown stack as a stack export (docs/format/stack.md)"),
            self._action(file_menu, "Export view as &PNG…", self.choose_png_export, "Ctrl+Shift+P",
                         "The image's data pixels, one per grid point, lossless"),
            self._action(file_menu, "Export view as shown, with &overlays (PNG)…", self.choose_shown_export,
                         "Ctrl+Shift+O", "The image panel at display scale: ring, region, scale bar, title"),
            self._action(file_menu, "Export scrub as &movie (MP4)…", self.choose_movie_export, "Ctrl+Shift+M"),
            self._action(file_menu, "Export profiles as &CSV…", self.choose_csv_export, "Ctrl+Shift+C"),
            self._action(file_menu, "Export &line profile as CSV…", self.choose_line_profile_export,
                         tip="Distances and values along the line of View > Line profile"),
            self._action(file_menu, "Export optical m&aps as EXR…", self.choose_optics_export,
                         tip="The Optics tab's mu_a and mu_s' maps, their standard errors and flags (as ringlight "
                             "optics --out)"),
        ]
        file_menu.addSeparator()
        self._action(file_menu, "&Quit", self.close, QKeySequence.StandardKey.Quit)

        view_menu = self.menuBar().addMenu("&View")
        for number, (key, label) in enumerate(VIEWS.items(), start=1):
            self._action(view_menu, label, lambda _=False, key=key: self.display_controls.set_view(key),
                         f"Ctrl+{number}")
        view_menu.addSeparator()
        self._action(view_menu, "Next radius", lambda: self.scrub_bar.step(1), "]")
        self._action(view_menu, "Previous radius", lambda: self.scrub_bar.step(-1), "[")
        self._action(view_menu, "Play / pause", self.scrub_bar.toggle_play, "Space")
        self._action(view_menu, "Pick radius for layers", self.layer_panel.pick_requested.emit, "P")
        self._action(view_menu, "Fit layers (inverse method)", self._fit_layers, "F")
        self._action(view_menu, "Layers tab", lambda: self.analysis_tabs.setCurrentWidget(self.layer_panel), "Ctrl+L")
        self._action(view_menu, "Optics tab: mu_a, mu_s' maps", self._show_optics,
                     tip="Absorption and reduced scattering of every pixel, fitted to its E(r) (Compute maps there)")
        self._action(view_menu, "Reset zoom", self._reset_zoom, "Ctrl+0")
        self.radius_mm_action = self._action(
            view_menu, "Radius in &mm", lambda _=False: self._apply_radius_unit(),
            tip="Label the profiles' radius axis in mm (grid steps x the dataset's pitch_mm; "
                "only for datasets whose manifest gives grid.pitch_mm)")
        self.radius_mm_action.setCheckable(True)
        self.radius_mm_action.setEnabled(False)
        self.structure_view_action = self._action(
            view_menu, "Open datasets at their &structure", lambda _=False: None,
            tip="A dataset opened for the first time is shown at the radius, point and levels where its "
                "structure stands out most; off: at radius 0 and the grid's centre")
        self.structure_view_action.setCheckable(True)
        self.structure_view_action.setChecked(True)
        self._action(view_menu, "Cancel running work", self.cancel_all, "Esc")
        view_menu.addSeparator()
        for dock in (self.display_dock, self.stack_dock, self.profile_dock, self.line_profile_dock):
            view_menu.addAction(dock.toggleViewAction())
        self._build_device_menu(self.menuBar().addMenu("&Settings"))
        help_menu = self.menuBar().addMenu("&Help")
        self._action(help_menu, "&Keyboard shortcuts", self._show_shortcuts, "F1")
        self._action(help_menu, "Dataset &information", self._show_dataset_information, "Ctrl+I",
                     "The dataset on screen: grid, frames, the responses' size, its store and the memory an open takes")
        self._action(help_menu, "&About ringlight", self._show_about)
