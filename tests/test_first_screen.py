"""The first screen (issue 39): a dataset opened for the first time shows its structure, and one
opened again keeps the view it was left at. Fresh settings, as a new user has them."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest
from PySide6.QtCore import QSettings
from ringlight.app.window import MainWindow

LOAD_TIMEOUT_MS = 120_000


@pytest.fixture
def new_user_window(qtbot, tmp_path):
    window = MainWindow(QSettings(str(tmp_path / "fresh.ini"), QSettings.Format.IniFormat))
    qtbot.addWidget(window)
    window.resize(1366, 768)
    window.show()
    qtbot.waitExposed(window)
    yield window
    window.shutdown()


def open_sample(qtbot, window, name):
    with qtbot.waitSignal(window.dataset_loaded, timeout=LOAD_TIMEOUT_MS):
        window.open_sample(name)


def bead_centre(height, width):
    """The red bead's centre from its scene, rescaled to the sample's grid."""
    scene = json.loads(resources.files("ringlight.resources.scenes").joinpath("red-bead.json").read_text())
    y, x, _ = scene["shapes"][0]["center"]
    return y * height / scene["grid"]["height"], x * width / scene["grid"]["width"]


def test_the_demo_opens_on_the_bead_at_a_radius_and_levels_where_it_shows(qtbot, new_user_window):
    window = new_user_window
    open_sample(qtbot, window, "red-bead")
    height, width = window.loaded.dataset.grid_shape
    true_y, true_x = bead_centre(height, width)
    assert np.hypot(window.picked[0] - true_y, window.picked[1] - true_x) <= 1.5
    assert window.stacks.pair.radii[window.radius_index()] > 0  # not T_0, the white square
    assert window.display_settings().normalisation == "range"
    image = window.current_image()
    # Levels: the image's 0.5th and 99.5th percentiles over all channels, so its values spread
    # over the display (T_0 at (0, robust max) used the top 2 % of it).
    np.testing.assert_allclose(window.current_levels(), np.percentile(image, [0.5, 99.5]), rtol=1e-5)
    message = window.statusBar().currentMessage()
    assert "structure" in message and "scrub" in message and "Layers" in message
    # Drawn whole, or cut with an ellipsis before the jobs' indicators: the whole line is the tooltip.
    shown = window.statusBar().shown_message()
    assert window.statusBar().toolTip() == message and (shown == message or message.startswith(shown[:-1]))


def test_a_layered_sample_opens_on_the_layers_tab(qtbot, new_user_window, place_sample):
    window = new_user_window
    place_sample("layers3")  # its 5000 frames as the first open writes them, written once for the run
    open_sample(qtbot, window, "layers3")
    assert window.analysis_tabs.currentWidget() is window.layer_panel
    assert window.radius_index() == 0 and window.display_settings().normalisation == "per-image"
    assert "uniform" in window.statusBar().currentMessage()


def test_a_dataset_opened_again_keeps_the_radius_and_point_it_was_left_at(qtbot, new_user_window):
    window = new_user_window
    open_sample(qtbot, window, "red-bead")
    window.set_radius(2.0)
    window.pick(10, 30)
    open_sample(qtbot, window, "star")
    assert window.stacks.pair.radii[window.radius_index()] == 1.0  # the star's own first view
    open_sample(qtbot, window, "red-bead")
    assert window.stacks.pair.radii[window.radius_index()] == 2.0
    assert window.picked == (10, 30)
