"""The window's Help menu texts and dialogs: keyboard shortcuts, About, and notices.

A mixin of :class:`ringlight.app.window.MainWindow`. Dialogs open without blocking the window.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

from PySide6.QtCore import Qt, QUrl
from PySide6.QtGui import QFontDatabase, QKeySequence
from PySide6.QtWidgets import (
    QDialog,
    QDialogButtonBox,
    QLabel,
    QMessageBox,
    QPlainTextEdit,
    QVBoxLayout,
    QWidget,
)

from .dataset_info import describe_dataset

PAPER = ('K. Nishino, A. Subpa-asa, Y. Asano, M. Shimano and I. Sato, "Variable Ring Light Imaging: '
         'Capturing Transient Subsurface Scattering with an Ordinary Camera", ECCV 2018')
README_SECTIONS = ("A five-minute tour", "Command line", "Documentation")
"""The README.md sections About points to, their headings as written there (Documentation links
the user guide, the format and the API reference in docs/)."""
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
        self._information("Keyboard shortcuts", "\n".join(self.shortcut_lines()), columns=True)

    def dataset_information(self) -> str:
        """What ``ringlight info`` says of the dataset on screen (its file checks aside), and how
        it is open; empty with none."""
        if self.loaded is None:
            return ""
        dataset = self.loaded.dataset
        opened = "in memory" if dataset.in_memory else "out of core: read from its store band by band"
        return "\n".join([*describe_dataset(dataset.manifest, radius=dataset.max_radius), f"opened       {opened}"])

    def _show_dataset_information(self) -> None:
        if self.loaded is None:
            self.statusBar().showMessage("No dataset open", 5000)
            return
        self._information("Dataset information", self.dataset_information(), columns=True)

    def _show_about(self) -> None:
        """About ringlight: version, paper, and the README's sections as links (opened by the desktop)."""
        dialog = QDialog(self)
        dialog.setWindowTitle("About ringlight")
        dialog.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        label = QLabel(about_html(_version(), readme_path()))
        label.setObjectName("about-text")
        label.setTextFormat(Qt.TextFormat.RichText)
        label.setOpenExternalLinks(True)
        label.setTextInteractionFlags(Qt.TextInteractionFlag.TextBrowserInteraction)
        label.setWordWrap(True)
        label.setMinimumWidth(460)
        _show_with_ok(dialog, label)

    def _information(self, title: str, text: str, columns: bool = False) -> None:
        """An information box; ``columns``: lines padded into columns, in a fixed-width font."""
        if columns:
            self._columns_dialog(title, text)
            return
        box = QMessageBox(QMessageBox.Icon.Information, title, text, QMessageBox.StandardButton.Ok, self)
        box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        box.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        box.open()  # not exec(): the window keeps running behind it

    def _columns_dialog(self, title: str, text: str) -> None:
        """``text`` in a fixed-width font, as wide as its longest line up to 90 % of the screen,
        and wrapped beyond it: a message box cut its lines at 800 px (the store's path in Dataset
        information, at 1366 x 768)."""
        dialog = QDialog(self)
        dialog.setWindowTitle(title)
        dialog.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        view = QPlainTextEdit(text)
        view.setObjectName("columns-text")
        view.setReadOnly(True)
        view.setFont(QFontDatabase.systemFont(QFontDatabase.SystemFont.FixedFont))
        view.setLineWrapMode(QPlainTextEdit.LineWrapMode.WidgetWidth)
        metrics = view.fontMetrics()
        lines = text.splitlines() or [""]
        screen = (self.screen() or dialog.screen()).availableGeometry()
        margin = 2 * view.frameWidth() + 2 * int(view.document().documentMargin()) + view.verticalScrollBar().sizeHint().width()
        width = min(max(metrics.horizontalAdvance(line) for line in lines) + margin, int(0.9 * screen.width()) - 40)
        view.setMinimumSize(width, min(metrics.lineSpacing() * (len(lines) + 2), int(0.8 * screen.height()) - 80))
        _show_with_ok(dialog, view)


def _show_with_ok(dialog: QDialog, content: QWidget) -> None:
    """Lay ``content`` out in ``dialog`` above an OK button and show it without blocking (not
    exec(): the window keeps running behind it)."""
    buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok)
    buttons.accepted.connect(dialog.accept)
    layout = QVBoxLayout(dialog)
    layout.addWidget(content)
    layout.addWidget(buttons)
    dialog.open()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ringlight")
    except PackageNotFoundError:
        return "(not installed)"


def readme_path() -> Path | None:
    """README.md at the root of the source tree ringlight runs from (an editable or source
    install), or None where it is not there (an installed wheel)."""
    import ringlight.app

    path = Path(ringlight.app.__file__).resolve().parents[1] / "README.md"
    return path if path.is_file() else None


def heading_anchor(heading: str) -> str:
    """The anchor GitHub and Markdown viewers give a heading ("Command line" -> "command-line")."""
    return re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")


def about_html(version: str, readme: Path | None) -> str:
    """The About text as rich text: the README's sections as file:// links to ``readme``, or
    named in plain text when there is no README to link to."""
    if readme is None:
        where = "README.md of the ringlight sources: " + ", ".join(
            f'"{html.escape(heading.split(":")[0])}"' for heading in README_SECTIONS)
    else:
        links = []
        for heading in README_SECTIONS:
            url = QUrl.fromLocalFile(str(readme))
            url.setFragment(heading_anchor(heading))
            links.append(f'<a href="{url.toString()}">{html.escape(heading.split(":")[0])}</a>')
        links[0] += " (this window)"
        where = f'<a href="{QUrl.fromLocalFile(str(readme)).toString()}">README.md</a>: ' + ", ".join(links)
    return (f"<p><b>ringlight {html.escape(version)}</b>: variable ring light imaging</p>"
            f"<p>Transient images of light inside translucent surfaces from a projector and a camera, "
            f"after {html.escape(PAPER)}.</p><p>{where}.</p><p>License: BSD-3-Clause.</p>")
