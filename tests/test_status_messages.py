"""A status-bar message about a dialog goes with the dialog (issue 39: "Export line profile: show
the line profile first" stayed for many actions after its dialog closed)."""

from __future__ import annotations

from PySide6.QtWidgets import QMessageBox


def visible_boxes(window):
    return [box for box in window.findChildren(QMessageBox) if box.isVisible()]


def test_an_error_s_status_message_is_cleared_when_its_dialog_closes(qtbot, window):
    window.line_profile_dock.hide()
    window.choose_line_profile_export()
    assert window.statusBar().currentMessage().startswith("Export line profile: Show the line profile first")
    (box,) = visible_boxes(window)
    box.button(QMessageBox.StandardButton.Ok).click()
    assert window.statusBar().currentMessage() == ""


def test_a_newer_message_stays_when_an_older_dialog_closes(qtbot, window):
    window.show_error("Export failed", "x.png: disk full")
    (box,) = visible_boxes(window)
    window.statusBar().showMessage("Exported y.png", 8000)
    box.button(QMessageBox.StandardButton.Ok).click()
    assert window.statusBar().currentMessage() == "Exported y.png"
