"""View > Line profile: a draggable line on the image and the values of the shown image along it
in a dock under the image (:class:`~ringlight.widgets.line_profile.LineProfileTool`).

A mixin of :class:`ringlight.app.window.MainWindow`: it reads the window's ``image_panel``,
``_shown_image`` and ``image_shown`` signal.
"""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtGui import QKeySequence
from ringlight.core.errors import RinglightError
from ringlight.widgets.line_profile import LineProfileTool

LINE_PROFILE_SHORTCUT = "Ctrl+Shift+L"


class LineProfileDock:
    """The line-profile tool and its dock (mixed into MainWindow)."""

    def _build_line_profile(self) -> None:
        """The tool and its dock, hidden; the dock's own toggle action turns the tool on and off.
        The left and right docks keep the bottom corners, so that the dock sits under the image
        and never makes the window taller."""
        self.setCorner(Qt.Corner.BottomLeftCorner, Qt.DockWidgetArea.LeftDockWidgetArea)
        self.setCorner(Qt.Corner.BottomRightCorner, Qt.DockWidgetArea.RightDockWidgetArea)
        self.line_profile = LineProfileTool(self.image_panel, self)
        self.line_profile_dock = self._dock("Line profile", self.line_profile.plot_widget,
                                            Qt.DockWidgetArea.BottomDockWidgetArea)
        self.line_profile_dock.hide()
        action = self.line_profile_dock.toggleViewAction()
        action.setShortcut(QKeySequence(LINE_PROFILE_SHORTCUT))
        action.setStatusTip("A line on the image (drag its ends) and the shown values along it")
        action.toggled.connect(self._on_line_profile_toggled)
        self.image_shown.connect(self._feed_line_profile)

    def _on_line_profile_toggled(self, shown: bool) -> None:
        if shown:
            self.line_profile.set_data(self._shown_image)
        self.line_profile.set_enabled(shown)

    def _feed_line_profile(self) -> None:
        if self.line_profile_dock.isVisible():
            self.line_profile.set_data(self._shown_image)

    def choose_line_profile_export(self) -> None:
        """File > Export line profile as CSV: the distances and values along the line."""
        if not self.line_profile_dock.isVisible():
            self.show_error("Export line profile", "Show the line profile first (View > Line profile, "
                            f"{LINE_PROFILE_SHORTCUT}).")
            return
        if path := self._save_path("Export line profile as CSV", "line_profile.csv", "CSV (*.csv)"):
            try:
                self.line_profile.save_csv(path, overwrite=True)  # the save dialog asked the user
            except (OSError, RinglightError) as error:
                self.show_error("Export failed", f"{path}: {error}")
                return
            self.statusBar().showMessage(f"Exported {path}", 8000)
