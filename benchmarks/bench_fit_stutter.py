"""Benchmark of the event loop while the Layers tab's inverse fit runs (not a test: prints
figures from one run).

The explorer opens a bundled sample (default layers3), the Layers tab's method is set to
inverse and Fit is pressed; meanwhile a 10 ms QTimer (a gap probe) records the gaps between its
ticks, with playback of the scrub bar on (as in the GUI walks of issue 39, which saw hundreds of
100-900 ms gaps under load). Printed: the fit's wall time, the longest gap, the 99th percentile
and the number of gaps over 50 and 100 ms (a gap over 50 ms is a stutter one notices). Run it with
the other cores busy (e.g. ``stress -c 2``) to see the loaded machine of the issue.

``--thread`` runs the fit as before issue 39, in the worker thread itself
(``ringlight.core.inversion.report.invert_region``), for a comparison on the same machine;
``--both`` alternates the two.

    python benchmarks/bench_fit_stutter.py [--sample layers3] [--repeats 2] [--thread | --both]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import numpy as np
from PySide6.QtCore import QEventLoop, QSettings, QTimer
from PySide6.QtWidgets import QApplication
import ringlight.app.layer_tab as layer_tab
from ringlight.app.fit_process import invert_region_apart
from ringlight.app.heap import settle_heap
from ringlight.core.inversion.report import invert_region
from ringlight.app.window import MainWindow
from ringlight.widgets.layer_panel import INVERSE

PROBE_MS = 10


def wait_for(signal, timeout_ms: int = 600_000) -> None:
    loop = QEventLoop()
    signal.connect(loop.quit)
    QTimer.singleShot(timeout_ms, loop.quit)
    loop.exec()


def in_thread(dataset, region, description, settings, progress):
    """The fit as it ran before: in the calling (worker) thread."""
    return invert_region(dataset, region, description, settings, lambda fraction, what: progress(fraction))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", default="layers3")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--thread", action="store_true", help="fit in the worker thread (before issue 39)")
    parser.add_argument("--both", action="store_true", help="alternate the thread and the process")
    args = parser.parse_args()
    modes = ["thread", "process"] if args.both else ["thread" if args.thread else "process"]
    app = QApplication.instance() or QApplication([])
    with tempfile.TemporaryDirectory() as folder:
        window = MainWindow(QSettings(str(Path(folder) / "settings.ini"), QSettings.Format.IniFormat))
        window.resize(1366, 768)
        window.show()
        settle_heap()
        window.open_sample(args.sample)
        wait_for(window.dataset_loaded)
        window.analysis_tabs.setCurrentWidget(window.layer_panel)
        window.layer_panel.method_box.setCurrentIndex(window.layer_panel.method_box.findData(INVERSE))
        window.scrub_bar.play_button.setChecked(True)
        for repeat, mode in ((r, m) for r in range(args.repeats) for m in modes):
            layer_tab.invert_region_apart = invert_region_apart if mode == "process" else in_thread
            ticks: list[float] = []
            probe = QTimer()
            probe.timeout.connect(lambda: ticks.append(time.perf_counter()))
            probe.start(PROBE_MS)
            started = time.perf_counter()
            window.layer_tab.fit()
            wait_for(window.fit_jobs.idle)
            seconds = time.perf_counter() - started
            probe.stop()
            gaps = np.diff(ticks) * 1000 if len(ticks) > 1 else np.zeros(1)
            print(f"fit {repeat + 1} of {args.sample} in a {mode}: {seconds:.1f} s, {len(ticks)} ticks of a {PROBE_MS} ms probe; "
                  f"longest gap {gaps.max():.0f} ms, 99th percentile {np.percentile(gaps, 99):.0f} ms, "
                  f"{int((gaps > 50).sum())} over 50 ms, {int((gaps > 100).sum())} over 100 ms; "
                  f"result: {'fitted' if window.layer_tab.inversion is not None else window.last_error or 'none'}")
        window.scrub_bar.play_button.setChecked(False)
        window.shutdown()
        window.close()
        window.deleteLater()
        app.processEvents()


if __name__ == "__main__":
    main()
