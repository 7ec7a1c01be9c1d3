"""Export work for the explorer: each function captures its inputs and returns a job
``work(progress)`` for :class:`~ringlight.widgets.jobs.JobSlot`. All writes are atomic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from ringlight.core import Stack, write_stack
from ringlight.core.colour.display import DisplaySettings, display_levels, render
from ringlight.core.colour.image_export import (
    ExportError,
    write_bytes,
    write_movie,
    write_png,
    write_text,
)
from ringlight.core.dataset.writer import refuse_dataset_file
from ringlight.core.optics import OpticalMaps
from ringlight.core.optics.map_file import write_maps
from ringlight.core.rings.profiles import PixelProfile, profile_csv


def stack_levels(stack: Stack, settings: DisplaySettings) -> list[tuple[float, float]]:
    """Levels of every image of ``stack`` under ``settings`` (one pair per radius)."""
    if settings.normalisation in ("global", "manual"):
        return [display_levels(stack.images, settings)] * len(stack.radii)
    return [display_levels(image, settings) for image in stack.images]


def stack_work(stack: Stack, folder: Path):
    """Write ``stack`` as a stack export (docs/format/stack.md)."""
    return lambda progress: write_stack(stack, folder, progress)


def png_work(pixels: np.ndarray, path: Path):
    """Write the shown (H, W, 3) uint8 pixels as PNG."""
    pixels = pixels.copy()

    def work(progress):
        write_png(path, pixels, overwrite=True)  # the save dialog asked the user
        progress(1.0)
        return path
    return work


def qimage_png(image, path: Path) -> bytes:
    """A QImage encoded as PNG in memory (``path`` names it in errors): written by
    :func:`~ringlight.core.colour.image_export.write_bytes`, a full disk is one line, and the
    name's extension does not matter."""
    from PySide6.QtCore import QBuffer, QByteArray, QIODevice

    data = QByteArray()
    buffer = QBuffer(data)
    buffer.open(QIODevice.OpenModeFlag.WriteOnly)
    if not image.save(buffer, "PNG"):
        raise ExportError(f"{path}: Qt could not encode the PNG")
    buffer.close()
    return bytes(data.data())


def qimage_work(image, path: Path):
    """Write a QImage (a grabbed panel) as PNG, atomically."""

    def work(progress):
        write_bytes(path, qimage_png(image, path), overwrite=True)  # the save dialog asked the user
        progress(1.0)
        return path
    return work


def movie_work(stack: Stack, settings: DisplaySettings, fps: float, path: Path):
    """Write the scrub over ``stack`` as an MP4, normalised as on screen, radius burnt in."""
    def work(progress):
        levels = stack_levels(stack, settings)
        step = f"  dr = {stack.step:g}" if stack.step is not None else ""
        symbol = "T" if stack.kind == "transient" else "E"
        labels = [f"{symbol}_r  r = {radius:g}{step}" for radius in stack.radii]
        return write_movie(
            path, lambda index: render(stack.images[index], levels[index], settings, stack.colorspace),
            labels, fps, progress, overwrite=True,  # the save dialog asked the user
        )
    return work


def csv_work(profile: PixelProfile, path: Path):
    """Write the picked pixel's profiles as CSV."""
    def work(progress):
        write_text(path, profile_csv(profile), overwrite=True)
        progress(1.0)
        return path
    return work


def optics_work(maps: OpticalMaps, path: Path, dataset_folder: Path):
    """Write the optical-property maps as one EXR file (the channels of ``ringlight optics --out``);
    never over a file of the dataset in ``dataset_folder`` they were computed from (a frame is an
    EXR file too), which the save dialog does not know."""
    def work(progress):
        refuse_dataset_file(path, dataset_folder)
        write_maps(maps, path, overwrite=True)  # the save dialog asked the user
        progress(1.0)
        return path
    return work
