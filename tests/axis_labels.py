"""The tick labels a pyqtgraph axis draws, for the tests that check labels are shown and right."""

from PySide6.QtGui import QImage, QPainter


def drawn_text_specs(axis) -> list:
    """``(rect, flags, text)`` of every tick label ``axis`` draws now (its own
    ``generateDrawSpecs``, on a scratch painter), rects in the axis's coordinates."""
    image = QImage(16, 16, QImage.Format.Format_ARGB32)
    painter = QPainter(image)
    try:
        return axis.generateDrawSpecs(painter)[2]
    finally:
        painter.end()
