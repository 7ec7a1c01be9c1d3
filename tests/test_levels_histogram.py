"""The levels histogram: drawn once per shown image, its range holding the values and levels."""

import numpy as np
import pytest

pytest.importorskip("PySide6")
from PySide6.QtWidgets import QApplication  # noqa: E402
from qt_paints import PaintCounter  # noqa: E402
from ringlight.core.colour.display import value_histogram  # noqa: E402
from ringlight.widgets.levels_histogram import LevelsHistogram  # noqa: E402


def test_each_new_image_paints_the_histogram_once(qtbot):
    """pyqtgraph updates a view's range while painting, which moved the items and asked for a
    second paint on every scrub step; the histogram now brings its range up to date first."""
    histogram = LevelsHistogram()
    qtbot.addWidget(histogram)
    histogram.resize(300, 100)
    histogram.show()
    qtbot.waitExposed(histogram)
    counter = PaintCounter(histogram.viewport())
    rng = np.random.default_rng(2)
    for scale in (1.0, 5.0, 0.2, 30.0):
        image = rng.gamma(2.0, scale, (64, 64, 3)).astype(np.float32)
        levels = (0.0, float(np.percentile(image, 99)))
        qtbot.wait(20)
        counter.count = 0
        histogram.set_image(image, levels)
        for _ in range(5):
            QApplication.processEvents()
        assert counter.count == 1
        edges, _ = value_histogram(image)
        low, high = histogram.getPlotItem().vb.viewRange()[0]
        assert low <= min(edges[0], levels[0]) and max(edges[-1], levels[1]) <= high
        assert histogram.region.getRegion() == pytest.approx(levels)
