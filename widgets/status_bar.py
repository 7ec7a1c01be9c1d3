"""A status bar whose temporary message is elided to the room its permanent widgets leave.

Qt draws a temporary message clipped at the first permanent widget shown (a running job's
indicator, the dataset's name), so a long line ran into the job's label and lost its end: the
first view's guidance was cut at "(Analysis > Layers" while the noise of a new dataset was
computed. Here the line ends in an ellipsis where it does not fit, and the whole line is the bar's
tooltip while it shows.
"""

from __future__ import annotations

from PySide6.QtCore import QRect, Qt
from PySide6.QtGui import QPainter
from PySide6.QtWidgets import QStatusBar, QWidget

MARGIN = 6
"""Pixels between the message and the bar's left edge, as Qt leaves them."""
GAP = 8
"""Pixels between the message and the first permanent widget shown."""


class ElidingStatusBar(QStatusBar):
    """:class:`QStatusBar` whose temporary message is elided (left to right layouts)."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        # Kept here: QStatusBar lists no permanent widgets, and its size grip, the other child shown
        # beside a message, is placed only once laid out (at 0, 0 until then).
        self._permanent: list[QWidget] = []
        self.messageChanged.connect(self.setToolTip)

    def addPermanentWidget(self, widget: QWidget, stretch: int = 0) -> None:
        self._permanent.append(widget)
        super().addPermanentWidget(widget, stretch)

    def insertPermanentWidget(self, index: int, widget: QWidget, stretch: int = 0) -> int:
        self._permanent.append(widget)
        return super().insertPermanentWidget(index, widget, stretch)

    def removeWidget(self, widget: QWidget) -> None:
        if widget in self._permanent:
            self._permanent.remove(widget)
        super().removeWidget(widget)

    def message_room(self) -> QRect:
        """Where the message is drawn: from the left margin to the first permanent widget shown."""
        right = self.width() - MARGIN
        for widget in self._permanent:
            if widget.isVisible():
                right = min(right, widget.geometry().left() - GAP)
        return QRect(MARGIN, 0, max(right - MARGIN, 0), self.height())

    def shown_message(self) -> str:
        """The temporary message as drawn: elided with "…" where wider than :meth:`message_room`."""
        return self.fontMetrics().elidedText(self.currentMessage(), Qt.TextElideMode.ElideRight,
                                             self.message_room().width())

    def paintEvent(self, event) -> None:
        if not self.currentMessage():
            super().paintEvent(event)
            return
        painter = QPainter(self)
        painter.setPen(self.palette().windowText().color())
        painter.drawText(self.message_room(),
                         Qt.AlignmentFlag.AlignLeading | Qt.AlignmentFlag.AlignVCenter | Qt.TextFlag.TextSingleLine,
                         self.shown_message())
