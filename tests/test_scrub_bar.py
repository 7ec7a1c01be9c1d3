"""The scrub bar: a radius typed directly shows the stack's nearest radius."""

import numpy as np
import pytest

pytest.importorskip("PySide6")
from ringlight.widgets.scrub_bar import ScrubBar  # noqa: E402


@pytest.mark.parametrize("typed, shown", [(3.0, 3.0), (3.4, 3.0), (3.6, 4.0), (99.0, 10.0)])
def test_typed_radius_shows_the_nearest_stack_radius(qtbot, typed, shown):
    bar = ScrubBar()
    qtbot.addWidget(bar)
    bar.set_radii(np.arange(0.0, 11.0))
    with qtbot.waitSignal(bar.index_changed, timeout=1000):
        bar.radius_box.setValue(typed)
    assert bar.radius() == shown and bar.radius_box.value() == shown
