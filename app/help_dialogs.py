"""The window's Help menu texts and dialogs: keyboard shortcuts, About, and notices.

A mixin of :class:`ringlight.app.window.MainWindow`. Dialogs open without blocking the window.
"""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import QMessageBox

ABOUT = """ringlight {version}: variable ring light imaging

Transient images of light inside translucent surfaces from a projector and a camera, after
K. Nishino, A. Subpa-asa, Y. Asano, M. Shimano and I. Sato, "Variable Ring Light Imaging:
Capturing Transient Subsurface Scattering with an Ordinary Camera", ECCV 2018.

README.md: "Explorer window" (this window), "Capture", "Command line", "Safety".
License: BSD-3-Clause."""
EXITANCE_NOTICE = """{path} was simulated by an earlier ringlight, whose frames hold exitance: all light
leaving each pixel in any direction, plus the specular reflection at the lit pixel. A camera sees the
radiance toward it, which has another radial shape (about 1.6x at the lit point, 0.6-0.85x one to
four steps away). Its profiles, transients and ground truth are not comparable with a capture.

Re-simulate it with this ringlight for camera-like data, for example:
    ringlight simulate PRESET_OR_SCENE.json --out NEW_FOLDER"""


class HelpDialogs:
    """Help > Keyboard shortcuts and About, and information boxes (mixed into MainWindow)."""

    def shortcut_lines(self) -> list[str]:
        """"KEYS  menu > action" for every menu action with a shortcut, read from the menus
        themselves so that the sheet always matches them, then the mouse gestures."""
        lines = []
        for menu_action in self.menuBar().actions():
            menu = menu_action.menu()
            for action in menu.actions() if menu is not None else ():
                keys = action.shortcut().toString(QKeySequence.SequenceFormat.NativeText)
                if keys:
                    lines.append(f"{keys:<14} {menu.title().replace('&', '')} > "
                                 f"{action.text().replace('&', '').rstrip('…')}")
        return lines + [
            "Left click or drag on the image: pick a pixel; wheel: zoom; middle drag: pan",
            "Click or drag in the profiles: set the radius",
        ]

    def _show_shortcuts(self) -> None:
        self._information("Keyboard shortcuts", "\n".join(self.shortcut_lines()))

    def _show_about(self) -> None:
        self._information("About ringlight", ABOUT.format(version=_version()))

    def _information(self, title: str, text: str) -> None:
        box = QMessageBox(QMessageBox.Icon.Information, title, text, QMessageBox.StandardButton.Ok, self)
        box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        box.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        box.open()  # not exec(): the window keeps running behind it


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ringlight")
    except PackageNotFoundError:
        return "(not installed)"
