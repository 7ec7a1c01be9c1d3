"""What the window remembers between runs: layout, display settings, the stack request, recent files,
the device.

A mixin of :class:`ringlight.app.window.MainWindow`, stored in the QSettings it was given.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from PySide6.QtCore import QSize
from PySide6.QtWidgets import QWidget
from ringlight.core.colour.display import DisplaySettings
from ringlight.core.rings.stack_request import StackRequest
from ringlight.widgets.display_controls import VIEWS

RECENT_LIMIT = 10
REQUEST_LIMIT = 50
"""Datasets whose stack request is remembered (the most recently shown)."""


def _request_key(path) -> str:
    return str(Path(path).resolve())


class WindowSettings:
    """Persistence of the window's state (mixed into MainWindow)."""

    def _remember_recent(self, path: Path) -> None:
        recent = [str(path)] + [entry for entry in self.recent_files() if entry != str(path)]
        self.settings.setValue("recent_files", json.dumps(recent[:RECENT_LIMIT]))
        self._rebuild_recent_menu()

    def recent_files(self) -> list[str]:
        try:
            recent = json.loads(self.settings.value("recent_files", "[]"))
        except (TypeError, ValueError):
            return []
        return [entry for entry in recent if isinstance(entry, str)]

    def _rebuild_recent_menu(self) -> None:
        self.recent_menu.clear()
        for number, entry in enumerate(self.recent_files(), start=1):
            action = self.recent_menu.addAction(f"&{number % 10} {entry}")
            action.triggered.connect(lambda _=False, entry=entry: self.open_dataset(entry))
        self.recent_menu.setEnabled(bool(self.recent_files()))

    def _saved_requests(self) -> dict[str, dict]:
        try:
            saved = json.loads(self.settings.value("stack_requests", "{}"))
        except (TypeError, ValueError):
            return {}
        return saved if isinstance(saved, dict) else {}

    def saved_request(self, path) -> StackRequest | None:
        """The stack request last shown for dataset ``path`` (the demo's is its sample's), if any.

        Requests are remembered per dataset: one clamped to a small dataset's max_radius must
        not become the next dataset's default.
        """
        try:
            return StackRequest(**self._saved_requests()[_request_key(path)])
        except (KeyError, TypeError, ValueError):
            return None

    def saved_view(self, path) -> tuple[float, tuple[int, int]] | None:
        """The radius (grid steps) and picked point last shown for dataset ``path``, if any."""
        try:
            saved = json.loads(self.settings.value("dataset_views", "{}"))[_request_key(path)]
            radius, (y, x) = float(saved["radius"]), saved["pick"]
            return radius, (int(y), int(x))
        except (KeyError, TypeError, ValueError):
            return None

    def _remember_request(self) -> None:
        """Remember the stack request, radius and pick shown for the dataset on screen."""
        if self.stacks is None or self.loaded is None:
            return
        key = _request_key(self.loaded.dataset.path)
        saved = self._saved_requests()
        saved.pop(key, None)
        saved[key] = asdict(self.stacks.pair.request)
        self.settings.setValue("stack_requests", json.dumps(dict(list(saved.items())[-REQUEST_LIMIT:])))
        try:
            views = json.loads(self.settings.value("dataset_views", "{}"))
        except (TypeError, ValueError):
            views = {}
        views = views if isinstance(views, dict) else {}
        views.pop(key, None)
        if self.picked is not None:
            views[key] = {"radius": float(self.stacks.pair.radii[self.radius_index()]), "pick": list(self.picked)}
        self.settings.setValue("dataset_views", json.dumps(dict(list(views.items())[-REQUEST_LIMIT:])))

    def _restore_settings(self) -> None:
        geometry = self.settings.value("geometry")
        if geometry is not None:
            self.restoreGeometry(geometry)
        state = self.settings.value("window_state")
        if state is not None:
            self.restoreState(state)
        try:
            document = json.loads(self.settings.value("display", ""))
            document["manual_levels"] = tuple(document["manual_levels"])
            self.display_controls.set_settings(DisplaySettings(**document))
        except (TypeError, ValueError, KeyError):
            pass
        try:
            for kind, name in json.loads(self.settings.value("colormaps", "{}")).items():
                self.display_controls.set_colormap_name(kind, name)
        except (TypeError, ValueError, KeyError, AttributeError):
            pass  # a map this version does not offer keeps the default
        view = self.settings.value("view", "transient")
        if view in VIEWS:
            self.display_controls.set_view(view)
        self.display_controls.profile_log_box.setChecked(self.settings.value("profile_log_y", "false") == "true")
        self.radius_mm_action.setChecked(self.settings.value("radius_in_mm", "false") == "true")
        self.structure_view_action.setChecked(self.settings.value("structure_view", "true") == "true")
        self.scrub_bar.fps_box.setValue(int(self.settings.value("fps", 8)))
        self.scrub_bar.loop_box.setChecked(self.settings.value("loop", "true") == "true")
        self._restore_device()
        self._rebuild_recent_menu()

    def save_settings(self) -> None:
        self.settings.setValue("geometry", self.saveGeometry())
        self.settings.setValue("window_state", self.saveState())
        self.settings.setValue("display", json.dumps(asdict(self.display_settings())))
        self.settings.setValue("view", self.view())
        self.settings.setValue("colormaps", json.dumps(self.display_controls.colormap_names()))
        self.settings.setValue("profile_log_y", "true" if self.profile_plot.log_y else "false")
        self.settings.setValue("radius_in_mm", "true" if self.radius_mm_action.isChecked() else "false")
        self.settings.setValue("structure_view", "true" if self.structure_view_action.isChecked() else "false")
        self.settings.setValue("fps", self.scrub_bar.fps_box.value())
        self.settings.setValue("loop", "true" if self.scrub_bar.loop_box.isChecked() else "false")
        self._save_device()
        self._remember_request()
        self.settings.sync()


def first_size(window: QWidget) -> QSize:
    """1400 x 860 pixels, or less where the screen is smaller (a 1366 x 768 laptop), leaving
    room for the window frame and title bar: saved geometry replaces it on later runs."""
    size = QSize(1400, 860)
    screen = window.screen()
    if screen is None:
        return size
    free = screen.availableGeometry().size()
    return size.boundedTo(QSize(free.width() - 16, free.height() - 48))
