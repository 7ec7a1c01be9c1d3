"""Benchmark of the explorer's interactive latency (not a test: prints figures from one run).

A synthetic 128 x 128 dataset (random responses, 2 % missing points, max_radius 24) with a
23-radius transient stack (r = 0..22, dr 1) is shown in the main window (offscreen, or on the
display given by QT_QPA_PLATFORM / DISPLAY). Timed, each from a synthetic Qt input event until the
affected views have been repainted: the event and everything it posts (scene updates, paint
requests) are processed by ``processEvents()``, and the paint events delivered in that interval
are counted to show that drawing happened inside it:
  - click: a left click on a random image pixel -> picked marker, ring overlay and both profile
    plots drawn, with their noise bands (timing starts once the noise has been computed);
  - step: a ``]`` / ``[`` key press -> the next transient image normalised, encoded and drawn.
Target (explorer issue): median < 16 ms for both (60 fps). ``--dataset PATH`` measures them on a
dataset folder instead (opened as the explorer would: read from its store, out of core when it
is over the memory budget; the paper-scale issue's target is an 800 px one).

Also measured: the longest event-loop stall (gap between ticks of a 5 ms QTimer) while the window
opens a 128 x 128 dataset from EXR frames (multiplexed, written first) and recomputes its stack
in worker threads. Target (paper-scale issue): no stall over 50 ms.

    python benchmarks/bench_gui.py [--size 128] [--max-radius 24] [--events 200] [--dataset PATH]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import numpy as np
from PySide6.QtCore import QEvent, QObject, QPointF, QSettings, Qt, QTimer
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication

sys.path.insert(0, str(Path(__file__).parent))
from bench_stack import synthetic_dataset  # noqa: E402
from ringlight.app.heap import settle_heap  # noqa: E402
from ringlight.app.session import LoadedDataset, compute_view_stacks  # noqa: E402
from ringlight.app.window import MainWindow  # noqa: E402
from ringlight.core import DatasetWriter, open_dataset  # noqa: E402
from ringlight.core.rings.stack_request import StackRequest  # noqa: E402


class PaintCounter(QObject):
    """Event filter recording which widgets received a paint event since :meth:`reset`."""

    def __init__(self):
        super().__init__()
        self.widgets: set[int] = set()

    def reset(self) -> None:
        self.widgets.clear()

    def painted(self, widget) -> bool:
        return id(widget) in self.widgets

    def eventFilter(self, watched, event) -> bool:
        if event.type() == QEvent.Type.Paint:
            self.widgets.add(id(watched))
        return False


class StallMeter(QObject):
    """Longest gap between ticks of a 5 ms timer: how long the event loop was blocked."""

    def __init__(self):
        super().__init__()
        self.timer = QTimer(self)
        self.timer.setInterval(5)
        self.timer.timeout.connect(self._tick)
        self.last = 0.0
        self.longest = 0.0

    def start(self) -> None:
        self.last, self.longest = time.perf_counter(), 0.0
        self.timer.start()

    def stop(self) -> float:
        self.timer.stop()
        return self.longest

    def _tick(self) -> None:
        now = time.perf_counter()
        self.longest = max(self.longest, now - self.last)
        self.last = now


def write_exr_dataset(folder: Path, size: int, max_radius: float) -> None:
    """A multiplexed dataset whose impulses fall off as exp(-d / 3) within ``max_radius``."""
    spacing = int(2 * max_radius) + 1
    yy, xx = np.mgrid[:size, :size]
    with DatasetWriter(folder, (size, size), max_radius=max_radius) as writer:
        for oy in range(spacing):
            for ox in range(spacing):
                lit = [(y, x) for y in range(oy, size, spacing) for x in range(ox, size, spacing)]
                frame = np.zeros((size, size, 3), np.float32)
                for y, x in lit:
                    distance = np.hypot(yy - y, xx - x)
                    frame += (np.exp(-distance / 3.0) * (distance <= max_radius))[..., None] * [1.0, 0.6, 0.3]
                writer.add_frame(frame, lit)


def wait_for(app, signal, timeout_s: float = 600.0) -> None:
    done = []
    signal.connect(lambda *args: done.append(True))
    deadline = time.perf_counter() + timeout_s
    while not done and time.perf_counter() < deadline:
        app.processEvents()
        time.sleep(0.001)


def measure_stalls(app, folder: Path, size: int) -> None:
    dataset_folder = folder / "dataset"
    started = time.perf_counter()
    write_exr_dataset(dataset_folder, size, 12.0)
    print(f"wrote a {size} x {size} EXR dataset (max_radius 12) in {time.perf_counter() - started:.1f} s")
    window = MainWindow(QSettings(str(folder / "stall.ini"), QSettings.Format.IniFormat))
    window.resize(1400, 860)
    window.show()
    settle_heap()  # as the app does once its window is up
    for _ in range(20):  # the new window's first paint is start-up, not part of opening
        app.processEvents()
        time.sleep(0.01)
    meter = StallMeter()
    meter.start()
    started = time.perf_counter()
    window.open_dataset(dataset_folder)
    wait_for(app, window.dataset_loaded)
    print(f"open from EXR + first stack: {time.perf_counter() - started:.2f} s, "
          f"longest event-loop stall {meter.stop() * 1e3:.1f} ms")
    meter.start()
    started = time.perf_counter()
    window.request_stacks(StackRequest(0.0, 10.0, 0.25, dr=0.25, thickness=1.0, antialias=True))
    wait_for(app, window.stacks_ready)
    print(f"recompute 41 anti-aliased radii: {time.perf_counter() - started:.2f} s, "
          f"longest event-loop stall {meter.stop() * 1e3:.1f} ms")
    window.shutdown()
    window.close()
    window.deleteLater()


def percentiles(times: list[float]) -> str:
    milliseconds = np.array(times) * 1e3
    return (f"median {np.median(milliseconds):6.2f} ms   p95 {np.percentile(milliseconds, 95):6.2f} ms   "
            f"max {milliseconds.max():6.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--max-radius", type=float, default=24.0)
    parser.add_argument("--events", type=int, default=200)
    parser.add_argument("--dataset", help="a dataset folder to measure clicks and steps on instead")
    args = parser.parse_args()

    app = QApplication.instance() or QApplication([])
    started = time.perf_counter()
    if args.dataset:
        dataset = open_dataset(args.dataset)
        print(f"opened {args.dataset} in {time.perf_counter() - started:.1f} s "
              f"({'in memory' if dataset.in_memory else 'out of core'})")
    else:
        dataset = synthetic_dataset(args.size, args.max_radius)
    started = time.perf_counter()
    stacks = compute_view_stacks(dataset, None, StackRequest(0.0, min(dataset.max_radius - 2, 20.0), 1.0, dr=1.0),
                                 lambda _: None)
    height, width = dataset.grid_shape
    print(f"{height} x {width}, max_radius {dataset.max_radius:g} (K = {len(dataset.offsets)}), "
          f"{len(stacks.pair.radii)} radii computed in {time.perf_counter() - started:.2f} s")
    with tempfile.TemporaryDirectory() as folder:
        window = MainWindow(QSettings(str(Path(folder) / "settings.ini"), QSettings.Format.IniFormat))
        window.resize(1400, 860)
        window.show()
        window._on_loaded(LoadedDataset(dataset, dataset.steady_state(), None, stacks))
        window.set_radius(8.0)
        deadline = time.perf_counter() + 600  # the noise (bands, SNR) is computed in a worker: wait for it,
        while window.noise is None and time.perf_counter() < deadline:  # as a user would see it
            app.processEvents()
            time.sleep(0.01)
        panel = window.image_panel
        rng = np.random.default_rng(1)
        # Clicks land on pixels a user can see: on a grid larger than the view, a zoomed-in
        # 128 x 128 window at its centre (a click there picks exactly the pixel aimed at).
        top, left = max(height // 2 - 64, 0), max(width // 2 - 64, 0)
        rows, columns = min(height, 128), min(width, 128)
        panel.view.setRange(xRange=(left, left + columns), yRange=(top, top + rows), padding=0)
        app.processEvents()

        paints = PaintCounter()
        app.installEventFilter(paints)

        clicks = []
        for _ in range(args.events):
            y, x = top + int(rng.integers(0, rows)), left + int(rng.integers(0, columns))
            position = panel.mapFromScene(panel.view.mapViewToScene(QPointF(x + 0.5, y + 0.5)))
            start = time.perf_counter()
            paints.reset()
            QTest.mouseClick(panel.viewport(), Qt.MouseButton.LeftButton, pos=position)
            app.processEvents()
            clicks.append(time.perf_counter() - start)
            assert window.picked == (y, x)
            assert paints.painted(panel.viewport()) and paints.painted(window.profile_plot.viewport())

        steps = []
        key = Qt.Key.Key_BracketRight
        for _ in range(args.events):
            if window.radius_index() == len(stacks.pair.radii) - 1:
                key = Qt.Key.Key_BracketLeft
            elif window.radius_index() == 0:
                key = Qt.Key.Key_BracketRight
            start = time.perf_counter()
            paints.reset()
            QTest.keyClick(window, key)
            app.processEvents()
            steps.append(time.perf_counter() - start)
            assert paints.painted(panel.viewport())

        print(f"click -> overlay + profiles drawn ({args.events}): {percentiles(clicks)}")
        print(f"slider step -> image drawn      ({args.events}): {percentiles(steps)}")
        print(f"target: median < 16 ms; ratios to target: click {np.median(clicks) * 1e3 / 16:.2f}, "
              f"step {np.median(steps) * 1e3 / 16:.2f}")
        window.shutdown()
        window.close()
        window.deleteLater()
        if not args.dataset:
            measure_stalls(app, Path(folder), args.size)


if __name__ == "__main__":
    main()
