"""A scripted GUI walk of the Layers tab's Region combo under faulthandler (issue 39's SIGSEGV).

Opens the demo in the explorer (offscreen unless QT_QPA_PLATFORM says otherwise), then WALKS
times sets Region to each mode and back to "All pixels", processing events and enumerating the
application's top-level widgets after each step, as the GUI walk that crashed did. A low
``GC_THRESHOLD`` (default 50 allocations) makes the cyclic garbage collector run often, so that
an object it frees at a bad moment shows within a few hundred walks. Before
``ringlight.widgets.image_panel._delete_menus`` it died with SIGSEGV inside
``QApplication.topLevelWidgets()``; it prints "walk done" and exits 0 now.

    python tools/walk_layers_tab.py [WALKS=200] [GC_THRESHOLD=50]
"""

from __future__ import annotations

import faulthandler
import gc
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from PySide6.QtCore import QCoreApplication, QEvent, QEventLoop, QSettings  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402
from ringlight.app.window import MainWindow  # noqa: E402


def main() -> int:
    faulthandler.enable()
    walks = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    threshold = int(sys.argv[2]) if len(sys.argv) > 2 else 50
    app = QApplication.instance() or QApplication([])
    with tempfile.TemporaryDirectory() as folder:
        window = MainWindow(QSettings(str(Path(folder) / "settings.ini"), QSettings.Format.IniFormat))
        window.resize(1366, 768)
        window.show()
        loop = QEventLoop()
        window.dataset_loaded.connect(loop.quit)
        window.open_dataset(None)
        loop.exec()
        window.analysis_tabs.setCurrentWidget(window.layer_panel)
        box = window.layer_panel.region_box
        gc.set_threshold(threshold)
        for _ in range(walks):
            for index in [*range(box.count()), 0]:
                box.setCurrentIndex(index)
                app.processEvents()
                QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
                for widget in app.topLevelWidgets():
                    widget.isVisible()
                    widget.objectName()
                    widget.geometry()
        print(f"walk done: {walks} walks, {len(app.topLevelWidgets())} top-level widgets")
        window.shutdown()
        window.close()
        window.deleteLater()
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
    return 0


if __name__ == "__main__":
    sys.exit(main())
