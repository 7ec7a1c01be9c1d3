"""Bringing pyqtgraph views up to date before they are painted.

pyqtgraph recomputes a view box's auto range and applies its view transform while painting
(``ViewBox.prepareForPaint``, on the scene's ``sigPrepareForPaint``); the new transform moves
every item, and the scene then asks for a second paint. :func:`settle`, called right after a
plot's data change, does that work first, so that the paint finds nothing left to change: one
paint per update instead of two.
"""

from __future__ import annotations

import pyqtgraph as pg


def settle(*views: pg.ViewBox) -> None:
    """Bring each of ``views`` (in order: a view whose range others link to comes first) up to date."""
    for view in views:
        view.prepareForPaint()
