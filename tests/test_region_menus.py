"""Switching the Layers tab's region leaves no top-level widget to the garbage collector (issue 39:
a GUI walk died with SIGSEGV right after Region went back to "All pixels", while it enumerated
the top-level widgets). pyqtgraph gives each ROI handle a parentless QMenu; freed by the cyclic
collector, one was deleted while ``QApplication.topLevelWidgets()`` built its list
(``tools/walk_layers_tab.py`` reproduces it: SIGSEGV within 200 walks before the fix)."""

from __future__ import annotations

import gc

import numpy as np
from PySide6.QtCore import QCoreApplication, QEvent
from PySide6.QtWidgets import QApplication, QMenu
from reference import random_impulses, write_dataset

LOAD_TIMEOUT_MS = 120_000


def handle_menus() -> int:
    return sum(isinstance(widget, QMenu) and widget.title() == "Handle" for widget in QApplication.topLevelWidgets())


def test_a_removed_region_s_handle_menus_are_deleted_between_events_not_by_the_collector(qtbot, window, tmp_path):
    path = tmp_path / "dataset"
    write_dataset(path, 9, 8, random_impulses(np.random.default_rng(2), 9, 8, support=4.0))
    with qtbot.waitSignal(window.dataset_loaded, timeout=LOAD_TIMEOUT_MS):
        window.open_dataset(path)
    box = window.layer_panel.region_box
    before = handle_menus()
    gc.disable()  # only what the window deletes itself counts, not what a collection would free
    try:
        box.setCurrentIndex(box.findData("polygon"))
        assert handle_menus() == before + 3  # a triangle: one handle per corner
        box.setCurrentIndex(box.findData("rectangle"))
        box.setCurrentIndex(box.findData("all"))
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
        assert handle_menus() == before
    finally:
        gc.enable()
