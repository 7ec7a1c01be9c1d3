"""Help > About: the version, the paper, and the README's sections as links that lead somewhere."""

import re
from importlib.metadata import version
from pathlib import Path

import pytest

pytest.importorskip("PySide6")
from PySide6.QtCore import QUrl  # noqa: E402
from PySide6.QtWidgets import QDialog, QLabel  # noqa: E402
from ringlight.app.help_dialogs import README_SECTIONS, about_html, heading_anchor  # noqa: E402

README = Path(__file__).resolve().parents[1] / "README.md"


def about_dialog(qtbot, window) -> QDialog:
    action = next(action for menu in window.menuBar().actions() if menu.menu()
                  for action in menu.menu().actions() if action.text() == "&About ringlight")
    action.trigger()
    qtbot.waitUntil(lambda: any(d.isVisible() and d.windowTitle() == "About ringlight"
                                for d in window.findChildren(QDialog)))
    return next(d for d in window.findChildren(QDialog) if d.windowTitle() == "About ringlight")


def test_about_names_the_version_and_the_paper(qtbot, window):
    dialog = about_dialog(qtbot, window)
    try:
        label = dialog.findChild(QLabel, "about-text")
        text = re.sub(r"<[^>]+>", "", label.text())
        assert f"ringlight {version('ringlight')}:" in text  # 0.1.0, from the installed package's metadata
        assert "K. Nishino" in text and "Variable Ring Light Imaging" in text and "ECCV 2018" in text
    finally:
        dialog.close()


def test_about_links_the_readme_sections_it_names(qtbot, window):
    if not README.is_file():
        pytest.skip("no README.md beside the tests")
    dialog = about_dialog(qtbot, window)
    try:
        label = dialog.findChild(QLabel, "about-text")
        assert label.openExternalLinks()
        links = [QUrl(href) for href in re.findall(r'href="([^"]+)"', label.text())]
        # The README itself, then one link per section, each to a heading README.md really has.
        assert len(links) == 1 + len(README_SECTIONS)
        assert all(link.isLocalFile() and Path(link.toLocalFile()) == README for link in links)
        headings = [line.lstrip("#").strip() for line in README.read_text(encoding="utf-8").splitlines()
                    if line.startswith("#")]
        anchors = {heading_anchor(heading) for heading in headings}
        assert [link.fragment() for link in links[1:]] == [
            "a-five-minute-tour", "command-line", "documentation"]
        assert all(link.fragment() in anchors for link in links[1:])
    finally:
        dialog.close()


def test_without_a_readme_about_names_the_sections_in_plain_text():
    text = about_html("9.9", None)
    assert "href" not in text and '"A five-minute tour", "Command line", "Documentation"' in text
