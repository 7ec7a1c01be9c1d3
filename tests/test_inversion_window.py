"""The Layers tab's inverse method in the window: fit in a worker with progress and cancel, the
table, the uncertainty regions on the diagram, the fit plot, and the JSON export."""

from __future__ import annotations

import json
from functools import partial

import numpy as np
from PySide6.QtCore import Qt
from ringlight.app import layer_tab
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.inversion.settings import InversionSettings, settings_from_text
from ringlight.core.inversion.report import invert_region
from ringlight.core.simulate.samples import sample_folder

TIMEOUT_MS = 240_000
FINAL_PHOTONS = 20_000
"""The final white runs' photons here: what the tab shows and does, not the fit's precision (the
default's 200 000 made this test fit for minutes; the tab has no field for it)."""


def test_inverse_method_fits_in_a_worker_and_shows_regions_fit_and_flags(qtbot, window, tmp_path, monkeypatch,
                                                                           place_sample):
    monkeypatch.setattr(layer_tab, "settings_from_text", partial(settings_from_text, final_photons=FINAL_PHOTONS))
    place_sample("layers3")  # as its first opening writes it (tests/test_first_screen.py), once for the whole run
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.open_sample("layers3")
    panel = window.layer_panel
    window.analysis_tabs.setCurrentWidget(panel)
    panel.method_box.setCurrentIndex(panel.method_box.findData("inverse"))
    assert panel.inverse_rows.isVisible() and not panel.picking_row.isVisible()
    assert "Press Fit" in panel.message_label.text()
    # The fit follows the dataset: layers3's manifest states n 1.3 and g 0.
    assert (panel.n_box.text(), panel.g_box.value()) == ("1.30", 0.0)
    assert panel.inversion_inputs()["n"] == 1.3
    panel.boundaries_edit.setText("2,5")
    panel.mus_edit.setText("0.5,0.5,1.5")
    panel.depth_box.setValue(24)

    # Esc cancels a running fit and says so.
    qtbot.keyClick(window, Qt.Key.Key_F)
    assert window.fit_jobs.busy
    with qtbot.waitSignal(window.fit_jobs.cancelled, timeout=TIMEOUT_MS):
        qtbot.keyClick(window, Qt.Key.Key_Escape)
    assert "cancelled" in panel.message_label.text()

    with qtbot.waitSignal(window.fit_jobs.finished, timeout=TIMEOUT_MS):
        qtbot.keyClick(window, Qt.Key.Key_F)
    shown = window.layer_tab.inversion
    # The same numbers as core computes for the same region and settings.
    dataset = open_dataset(sample_folder("layers3"))
    settings = InversionSettings(3, (2, 5), (0.5, 0.5, 1.5), 1.3, 0.0, 24.0, final_photons=FINAL_PHOTONS)
    expected = invert_region(dataset, np.ones(dataset.grid_shape, bool), "all pixels", settings).inversion
    np.testing.assert_allclose([l.xy for l in shown.inversion.layers], [l.xy for l in expected.layers], atol=1e-9)
    assert [panel.table.item(row, 9).text() for row in range(3)] == ["yes", "yes", "no"]
    assert "absorption in G" in panel.table.item(2, 9).toolTip()
    # Beside each region's width, the width the data allow.
    assert [panel.table.item(row, 8).text() for row in range(3)] == [
        f"{l.region_width:.3f} (data {l.allowed_width:.3f})" for l in expected.layers]
    assert panel.table.item(0, 4).text() == "#%02x%02x%02x" % expected.layers[0].swatch
    # Three regions on the diagram; the undetermined base dashed and grey.
    regions = panel.diagram._regions
    assert len(regions) == 3
    assert regions[2].opts["pen"].style() == Qt.PenStyle.DashLine
    assert regions[0].opts["pen"].style() == Qt.PenStyle.SolidLine
    np.testing.assert_allclose(regions[0].getData()[0][:-1], shown.inversion.layers[0].region[:, 0])
    # The fit plot: measured points and a model line per channel, residuals below.
    model_lines = [item for _, item in panel.fit_plot._items if hasattr(item, "opts") and item.opts.get("name", "")
                   and item.opts["name"].endswith("model")]
    assert len(model_lines) == 3
    np.testing.assert_allclose(10 ** model_lines[2].getData()[1], expected.model[:, 2], rtol=1e-9)  # log y
    assert "Chi-square" in panel.message_label.text() and "Not determined: layer 3" in panel.message_label.text()

    with qtbot.waitSignal(window.export_jobs.finished, timeout=TIMEOUT_MS):
        window.layer_tab.export("json", tmp_path / "inverse.json")
    document = json.loads((tmp_path / "inverse.json").read_text())
    assert document["method"] == "inverse" and [l["determined"] for l in document["layers"]] == [True, True, False]

    # Changing a setting makes the shown fit stale: the table empties until the next fit. Below 1
    # the index reads auto: searched.
    panel.n_box.setValue(panel.n_box.minimum())
    assert panel.n_box.text() == "auto" and panel.inversion_inputs()["n"] is None
    window.layer_tab.refresh()
    assert panel.table.rowCount() == 0 and "Press Fit" in panel.message_label.text()
    # A setting that cannot work is refused in the tab, in one line, and nothing starts.
    panel.boundaries_edit.setText("5,two")
    qtbot.keyClick(window, Qt.Key.Key_F)
    assert not window.fit_jobs.busy
    assert panel.message_label.text() == "boundaries '5,two' must be numbers separated by commas"
