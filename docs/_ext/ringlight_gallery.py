"""sphinx-gallery hooks: each example writes into a fresh temporary folder, and the PNG files it
writes there are shown in the gallery as its figures. A folder is removed once its example has
run (when the next one starts; the last when the build ends), and ``tempfile`` points at the
system's temporary folder again.

The examples draw with ringlight's own display pipeline and save PNGs (no matplotlib), so the
gallery's image scraper collects those files instead of matplotlib figures.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from sphinx_gallery.scrapers import figure_rst

_FOLDERS: list[Path] = []
_BASE = tempfile.gettempdir()
"""The system's temporary folder, before the first example's folder replaces it in ``tempfile``."""


def reset_example_folder(gallery_conf, fname, when=None):
    """Point ``tempfile`` at a new, empty folder before each example runs, removing the last
    example's (its figures are copied into the gallery by then)."""
    remove_example_folders()
    folder = Path(tempfile.mkdtemp(prefix="ringlight-gallery-", dir=_BASE))
    _FOLDERS.append(folder)
    tempfile.tempdir = str(folder)


def remove_example_folders(app=None, exception=None) -> None:
    """Remove the examples' folders and point ``tempfile`` at the system's temporary folder again
    (also Sphinx's ``build-finished`` handler)."""
    while _FOLDERS:
        shutil.rmtree(_FOLDERS.pop(), ignore_errors=True)
    tempfile.tempdir = None


class ExampleFileScraper:
    """Show the PNG files the current example has written since its last code block."""

    def __init__(self):
        self._shown: set[Path] = set()

    def __call__(self, block, block_vars, gallery_conf):
        if not _FOLDERS:
            return ""
        written = sorted(path for path in _FOLDERS[-1].rglob("*.png") if path not in self._shown)
        targets = []
        for path, target in zip(written, block_vars["image_path_iterator"]):
            shutil.copyfile(path, target)
            self._shown.add(path)
            targets.append(target)
        return figure_rst(targets, gallery_conf["src_dir"])


scrape_example_files = ExampleFileScraper()
"""The gallery's image scraper (``conf.py`` names it)."""


def setup(app):
    """Sphinx extension entry: the last example's folder is removed when the build ends."""
    app.connect("build-finished", remove_example_folders)
    return {"parallel_read_safe": True}
