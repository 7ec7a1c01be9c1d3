"""Starting the explorer: the interactive window, or one offscreen screenshot (``--screenshot``)."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from ringlight.core import RinglightError
from ringlight.core.atomic import check_output_file
from ringlight.core.dataset.writer import refuse_dataset_file
from ringlight.core.colour.image_export import write_bytes

from .heap import settle_heap

APPLICATION = "ringlight"


def parse_pick(text: str | None) -> tuple[int, int] | None:
    """``"Y,X"`` -> (y, x); raises ValueError for anything else."""
    if text is None:
        return None
    parts = text.split(",")
    if len(parts) != 2:
        raise ValueError(f"--pick {text!r} must be Y,X, e.g. 16,20")
    try:
        y, x = (int(part) for part in parts)
    except ValueError:
        raise ValueError(f"--pick {text!r} must be two whole numbers Y,X, e.g. 16,20") from None
    return (y, x)


def run(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """Run the window (or the screenshot) for parsed command-line ``args``."""
    try:
        pick = parse_pick(args.pick)
    except ValueError as error:
        parser.error(str(error))
    alone = [option for option, given in (("--radius", args.radius is not None), ("--pick", pick is not None),
                                          ("--overwrite", args.overwrite)) if given]
    if alone and not args.screenshot:
        parser.error(f"{' and '.join(alone)} go{'es' if len(alone) == 1 else ''} with --screenshot")
    if args.screenshot is not None and not args.screenshot.strip():
        parser.error("--screenshot needs a file name")
    if args.radius is not None and not 0 <= args.radius < float("inf"):
        parser.error(f"--radius must be a finite number >= 0, got {args.radius}")
    if args.screenshot and not os.environ.get("QT_QPA_PLATFORM"):
        os.environ["QT_QPA_PLATFORM"] = "offscreen"
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QApplication

    from .window import MainWindow

    _quiet_offscreen_warnings()
    app = QApplication.instance() or QApplication([sys.argv[0]])
    app.setOrganizationName(APPLICATION)
    app.setApplicationName(APPLICATION)
    if args.screenshot:
        return take_screenshot(args.dataset, Path(args.screenshot), args.radius, pick, args.overwrite)
    window = MainWindow(QSettings())
    window.show()
    settle_heap()
    window.open_dataset(args.dataset)
    status = app.exec()
    _dispose(window)
    return status


def take_screenshot(dataset: str | None, out: Path, radius: float | None, pick: tuple[int, int] | None,
                    overwrite: bool = False) -> int:
    """Open ``dataset`` (None: the demo) in a fresh window with default settings, show
    ``radius`` and ``pick``, save the window as PNG to ``out`` and return an exit status."""
    from PySide6.QtCore import QCoreApplication, QEventLoop, QSettings

    try:
        if out.suffix.lower() != ".png":
            raise RinglightError(f"{out}: a screenshot is written as PNG: give a name ending in .png")
        check_output_file(out, overwrite, probe=True, overwrite_option="--overwrite")  # before any window
        if dataset is not None:
            refuse_dataset_file(out, dataset)
    except RinglightError as error:
        print(f"ringlight: error: {error}", file=sys.stderr)
        return 2

    from .exports import qimage_png
    from .window import MainWindow

    with tempfile.TemporaryDirectory() as folder:
        window = MainWindow(QSettings(str(Path(folder) / "settings.ini"), QSettings.Format.IniFormat))
        try:
            window.resize(1400, 860)
            window.show()
            loop = QEventLoop()
            window.dataset_loaded.connect(loop.quit)
            window.error_shown.connect(loop.quit)
            window.open_dataset(dataset)
            loop.exec()
            if window.loaded is None:
                print(f"ringlight: error: {window.last_error.splitlines()[0]}", file=sys.stderr)
                return 2
            height, width = window.loaded.dataset.grid_shape
            if pick is not None:
                if not (0 <= pick[0] < height and 0 <= pick[1] < width):
                    print(f"ringlight: error: --pick {pick[0]},{pick[1]} is outside the {height}x{width} grid",
                          file=sys.stderr)
                    return 2
                window.pick(*pick)
            if radius is not None:
                shown = window.loaded.stacks.pair.radii
                if not shown[0] - 1e-9 <= radius <= shown[-1] + 1e-9:
                    print(f"ringlight: error: --radius {radius:g} is outside the stack shown "
                          f"(radii {shown[0]:g}..{shown[-1]:g})", file=sys.stderr)
                    return 2
                window.set_radius(radius)
            QCoreApplication.processEvents()  # pending layout (panels shown on load) before the grab
            try:
                write_bytes(out, qimage_png(window.grab().toImage(), out), overwrite=overwrite)
            except RinglightError as error:  # a full disk: nothing is published under the name
                print(f"ringlight: error: {error}", file=sys.stderr)
                return 2
        finally:
            window.shutdown()
            window.close()
            _dispose(window)
    print(f"wrote {out}")
    return 0


def _quiet_offscreen_warnings() -> None:
    """Drop the offscreen platform's "does not support propagateSizeHints()" notice: it is
    printed for every window and says nothing to a user."""
    from PySide6.QtCore import qInstallMessageHandler

    previous = None

    def handler(kind, context, message):
        if "propagateSizeHints" in message:
            return
        if previous is not None:
            previous(kind, context, message)
        else:
            sys.stderr.write(message + "\n")

    previous = qInstallMessageHandler(handler)


def _dispose(window) -> None:
    """Destroy ``window`` now, while the QApplication exists: left to Python's exit-time garbage
    collection, pyqtgraph scenes can outlive the application and crash the interpreter."""
    from PySide6.QtCore import QCoreApplication, QEvent

    window.deleteLater()
    QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
