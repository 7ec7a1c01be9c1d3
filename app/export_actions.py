"""The window's export actions: ask for a path, then write in the export worker.

A mixin of :class:`ringlight.app.window.MainWindow`; the writing itself is in
:mod:`ringlight.app.exports` and core.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import QFileDialog

from . import exports


class ExportActions:
    """File > Export and the Layers tab's exports (mixed into MainWindow)."""

    def _save_path(self, title: str, name: str, pattern: str) -> Path | None:
        start = Path(self.settings.value("export_folder", str(Path.home()))) / name
        path, _ = QFileDialog.getSaveFileName(self, title, str(start), pattern)
        if not path:
            return None
        self.settings.setValue("export_folder", str(Path(path).parent))
        return Path(path)

    def _shown_stack(self):
        return self.stacks.pair.ring if self.view() == "ring" else self.stacks.pair.transient

    def choose_stack_export(self) -> None:
        if self.stacks is not None and (path := self._save_path(
                "Export stack as EXR: name a new folder (or an earlier stack export)",
                f"{self._shown_stack().kind}-stack", "Stack folder (*)")):
            self.export_stack(path)

    def choose_png_export(self) -> None:
        if self.stacks is not None and (path := self._save_path("Export view as PNG", "view.png", "PNG (*.png)")):
            self.export_png(path)

    def choose_shown_export(self) -> None:
        if self.stacks is not None and (path := self._save_path(
                "Export view as shown (PNG)", "view-shown.png", "PNG (*.png)")):
            self.export_shown(path)

    def choose_movie_export(self) -> None:
        if self.stacks is not None and (path := self._save_path("Export scrub as MP4", "scrub.mp4", "MP4 (*.mp4)")):
            self.export_movie(path)

    def choose_csv_export(self) -> None:
        if self.profile is not None and (path := self._save_path("Export profiles as CSV", "profile.csv",
                                                                 "CSV (*.csv)")):
            self.export_csv(path)

    def choose_layer_export(self, kind: str) -> None:
        patterns = {"json": "JSON (*.json)", "csv": "CSV (*.csv)", "png": "PNG (*.png)"}
        name = "chromaticity.png" if kind == "png" else f"layers.{kind}"
        if path := self._save_path(f"Export layers as {kind.upper()}", name, patterns[kind]):
            self.layer_tab.export(kind, path)

    def choose_optics_export(self) -> None:
        """File > Export optical maps: the Optics tab's maps as one EXR file."""
        if self.optics is None:
            self.show_error("Export optical maps", "Compute the maps first (Analysis > Optics, Compute maps).")
            return
        if path := self._save_path("Export optical maps as EXR", "optics-maps.exr", "EXR (*.exr)"):
            self.export_optics(path)

    def export_optics(self, path: Path) -> None:
        """Write the maps on the Optics tab, their standard errors and flags (as ``ringlight optics
        --out``) to ``path`` in a worker."""
        self.export_jobs.start(f"Writing {path.name}",
                               exports.optics_work(self.optics, path, self._optics_dataset.manifest.folder))

    def export_stack(self, folder: Path) -> None:
        """Write the shown stack (E_r or T_r) to ``folder`` in a worker."""
        self.export_jobs.start(f"Exporting stack to {folder.name}", exports.stack_work(self._shown_stack(), folder))

    def export_png(self, path: Path) -> None:
        self.export_jobs.start(f"Writing {path.name}", exports.png_work(self.image_panel.pixels(), path))

    def export_shown(self, path: Path) -> None:
        """Write the image panel as it is drawn (display scale, with its overlays) as PNG."""
        image = self.image_panel.grab().toImage()  # grabbed here; QImage may be saved off the GUI thread
        self.export_jobs.start(f"Writing {path.name}", exports.qimage_work(image, path))

    def export_movie(self, path: Path) -> None:
        self.export_jobs.start(
            f"Writing {path.name}",
            exports.movie_work(self._shown_stack(), self.display_settings(), self.scrub_bar.fps_box.value(), path),
        )

    def export_csv(self, path: Path) -> None:
        self.export_jobs.start(f"Writing {path.name}", exports.csv_work(self.profile, path))
