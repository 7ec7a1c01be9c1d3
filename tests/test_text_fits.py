"""No text cut off in the window at 1366 x 768 (issue 39): the status bar with a region drawn,
the difference view's title under its colour bar, the inverse table's headers, and the store's
path in Help > Dataset information. Each checked by geometry: the width a text needs in its
widget's font (QFontMetrics) against the width it has."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QCoreApplication
from PySide6.QtWidgets import QPlainTextEdit
from reference import random_impulses, write_truth_dataset
from ringlight.core.dataset import open_plan

LOAD_TIMEOUT_MS = 120_000
HEIGHT, WIDTH = 30, 28


def open_with_truth(qtbot, window, tmp_path):
    rng = np.random.default_rng(6)
    impulses = random_impulses(rng, HEIGHT, WIDTH, support=6.0)
    truth = [rng.uniform(0, 1, (HEIGHT, WIDTH, 3)).astype(np.float32) for _ in range(8)]
    # A long folder name, as a user's dataset has: the status bar must still hold the readout.
    path = write_truth_dataset(tmp_path / ("capture-2026-11-26-marble-slab-left-half-" + "x" * 40), HEIGHT, WIDTH,
                               impulses, truth, 6.0)
    with qtbot.waitSignal(window.dataset_loaded, timeout=LOAD_TIMEOUT_MS):
        window.open_dataset(path)
    if window.noise_jobs.busy:  # the readout's standard errors make it longest
        with qtbot.waitSignal(window.noise_jobs.idle, timeout=LOAD_TIMEOUT_MS):
            pass


def fits(label) -> bool:
    return label.fontMetrics().horizontalAdvance(label.text()) <= label.width()


def test_status_bar_readouts_fit_with_a_region_drawn(qtbot, window, tmp_path):
    open_with_truth(qtbot, window, tmp_path)
    window.analysis_tabs.setCurrentWidget(window.layer_panel)
    box = window.layer_panel.region_box
    box.setCurrentIndex(box.findData("rectangle"))
    window._on_hover(HEIGHT // 2, WIDTH // 2)
    window.statusBar().clearMessage()
    QCoreApplication.processEvents()
    assert "±" in window.hover_label.text() and "ring points" in window.hover_label.text()
    assert fits(window.hover_label), (window.hover_label.text(), window.hover_label.width())
    assert fits(window.dataset_label), (window.dataset_label.text(), window.dataset_label.width())
    region = window.region_label
    assert region.isVisible() and region.text().startswith("region: ")
    # Wrapped at word boundaries: each word fits, and the height holds every line.
    metrics = region.fontMetrics()
    assert max(metrics.horizontalAdvance(word) for word in region.text().split()) <= region.width()
    assert region.height() >= region.heightForWidth(region.width())


def test_the_difference_title_wraps_within_its_panel(qtbot, window, tmp_path):
    open_with_truth(qtbot, window, tmp_path)
    window.display_controls.set_view("difference")
    QCoreApplication.processEvents()
    title = window.image_panel.title
    assert "RMS diff / RMS T_r" in title.toPlainText()
    document = title.textItem.document()
    assert document.idealWidth() <= window.image_panel.view.width()


def test_inverse_table_headers_are_whole_and_their_columns_no_wider(qtbot, window, tmp_path):
    """Ten columns of 100 px each made the table 1000 px wide in a dock of under 400: scrolled,
    "depth" and "xy error" showed as "ept" and "xy erro". Each column is now as wide as its
    header (its text plus the style's padding, at most 24 px), so the table scrolls less."""
    open_with_truth(qtbot, window, tmp_path)
    panel = window.layer_panel
    panel.method_box.setCurrentIndex(panel.method_box.findData("inverse"))
    QCoreApplication.processEvents()
    header = panel.table.horizontalHeader()
    for column in range(panel.table.columnCount()):
        text = panel.table.horizontalHeaderItem(column).text()
        needed = header.fontMetrics().horizontalAdvance(text)
        assert needed <= header.sectionSize(column) <= needed + 24, (text, needed, header.sectionSize(column))


def test_dataset_information_shows_the_store_path_whole(qtbot, window, tmp_path, monkeypatch):
    open_with_truth(qtbot, window, tmp_path)
    # The text states the memory budget, a share of the memory available at the call: held still
    # here, so that the view's text and the one made again below agree (they differed by 0.1 GiB).
    budget = open_plan.memory_budget()
    monkeypatch.setattr(open_plan, "memory_budget", lambda: budget)
    window._show_dataset_information()
    QCoreApplication.processEvents()
    views = [view for view in window.findChildren(QPlainTextEdit, "columns-text") if view.isVisible()]
    assert len(views) == 1
    view = views[0]
    assert view.toPlainText() == window.dataset_information()
    assert str(window.loaded.dataset.path) in view.toPlainText()
    # Every line is shown: wrapped at the view's width, never cut or scrolled sideways.
    assert view.lineWrapMode() == QPlainTextEdit.LineWrapMode.WidgetWidth
    assert not view.horizontalScrollBar().isVisible()
    view.window().close()
