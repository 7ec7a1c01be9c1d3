"""Writing what the explorer shows: PNG images, MP4 movies with the radius burnt in, CSV text.

Every writer is atomic (a temporary file beside the target, renamed into place) and publishes a
file only once it is complete and checked: PNG and text are encoded in memory and written by
:func:`write_bytes`, which checks every byte reached the disk (a full disk, a quota or a file-size
limit is one :class:`~ringlight.core.atomic.OutputError` naming the file); a movie, which the
encoder writes itself, is read back and must hold every frame. A PNG's encoding does not depend on
its name's extension. An existing file is replaced only with ``overwrite=True`` (the window passes
it once its save dialog has asked the user; the rule of :mod:`ringlight.core.atomic`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from ..atomic import OutputError, atomic_file

MOVIE_MIN_WIDTH = 512
"""Movies of small grids are enlarged (nearest neighbour, integer factor) to at least this width
so that the burnt-in radius is legible and pixels stay sharp."""


class ExportError(OutputError):
    """An export could not be written."""


def write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False) -> Path:
    """Write ``data`` atomically and durably, publishing the file only once its size on the disk
    is ``len(data)``: a full disk is :class:`~ringlight.core.atomic.OutputError` naming ``path``,
    never a short file under its name."""
    path = Path(path)
    with atomic_file(path, overwrite=overwrite, durable=True) as temporary:
        with open(temporary, "wb") as file:
            file.write(data)
        written = temporary.stat().st_size
        if written != len(data):
            raise ExportError(f"{path}: only {written} of {len(data)} bytes reached the disk; nothing was written")
    return path


def png_bytes(pixels: np.ndarray, path: str | os.PathLike = "PNG") -> bytes:
    """(H, W, 3) uint8 RGB ``pixels`` encoded as a lossless PNG (``path`` names it in errors)."""
    pixels = _checked_rgb(pixels, Path(path))
    encoded, data = cv2.imencode(".png", cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR))
    if not encoded:
        raise ExportError(f"{path}: OpenCV could not encode the PNG")
    return data.tobytes()


def write_png(path: str | os.PathLike, pixels: np.ndarray, *, overwrite: bool = False) -> Path:
    """Write (H, W, 3) uint8 RGB ``pixels`` as a lossless PNG, atomically, whatever the name's extension."""
    return write_bytes(path, png_bytes(pixels, path), overwrite=overwrite)


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Write ``text`` (UTF-8: CSV, JSON) atomically."""
    return write_bytes(path, text.encode("utf-8"), overwrite=overwrite)


def movie_scale(width: int) -> int:
    """Integer enlargement that brings ``width`` to at least :data:`MOVIE_MIN_WIDTH`."""
    return max(1, -(-MOVIE_MIN_WIDTH // max(width, 1)))


def write_movie(
    path: str | os.PathLike,
    frame_at: Callable[[int], np.ndarray],
    labels: Sequence[str],
    fps: float,
    progress: Callable[[float], None] | None = None,
    *,
    overwrite: bool = False,
) -> Path:
    """Write an MP4 (MPEG-4 part 2, OpenCV VideoWriter) of ``len(labels)`` frames, atomically.

    ``frame_at(i)`` returns frame ``i`` as (H, W, 3) uint8 RGB; ``labels[i]`` is burnt into its
    top-left corner (e.g. ``"r = 4.0"``). Frames are enlarged by :func:`movie_scale` and padded
    to even sizes, which the codec needs. ``progress`` may raise Cancelled; nothing is left then.
    """
    path = Path(path)
    if not labels:
        raise ExportError(f"{path}: a movie needs at least one frame")
    if not fps > 0:
        raise ExportError(f"{path}: frame rate must be > 0, got {fps}")
    if path.suffix.lower() != ".mp4":  # the encoder picks its container by the name
        raise ExportError(f"{path}: a movie's name must end in .mp4")
    with atomic_file(path, overwrite=overwrite, durable=True) as temporary:
        first = _checked_rgb(frame_at(0), path)
        scale = movie_scale(first.shape[1])
        height = first.shape[0] * scale + (first.shape[0] * scale) % 2
        width = first.shape[1] * scale + (first.shape[1] * scale) % 2
        writer = cv2.VideoWriter(str(temporary), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (width, height))
        if not writer.isOpened():
            raise ExportError(f"{path}: OpenCV could not start an MP4 file here (no MP4 encoder, or the disk is full)")
        try:
            for index, label in enumerate(labels):
                frame = first if index == 0 else _checked_rgb(frame_at(index), path)
                writer.write(_movie_frame(frame, label, scale, (height, width)))
                if progress is not None:
                    progress((index + 1) / len(labels))
        finally:
            writer.release()
        readable = _readable_frames(temporary, len(labels))
        if readable != len(labels):  # the encoder says nothing of a failed write (a full disk)
            raise ExportError(f"{path}: the movie could not be written whole ({readable} of {len(labels)} "
                              "frames readable; is the disk full?); nothing was written")
    return path


def _readable_frames(path: Path, expected: int) -> int:
    """How many frames a decoder reads from the movie at ``path`` (at most ``expected`` + 1)."""
    capture = cv2.VideoCapture(str(path))
    try:
        count = 0
        while count <= expected and capture.isOpened() and capture.grab():
            count += 1
        return count
    finally:
        capture.release()


def _movie_frame(frame: np.ndarray, label: str, scale: int, size: tuple[int, int]) -> np.ndarray:
    enlarged = np.repeat(np.repeat(frame, scale, axis=0), scale, axis=1)
    canvas = np.zeros((*size, 3), np.uint8)
    canvas[:enlarged.shape[0], :enlarged.shape[1]] = enlarged
    canvas = cv2.cvtColor(canvas, cv2.COLOR_RGB2BGR)
    font_scale = max(0.6, size[1] / 600)
    thickness = max(1, int(round(1.5 * font_scale)))
    (text_width, text_height), baseline = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, font_scale, thickness)
    margin = int(6 * font_scale)
    banner = canvas[:text_height + baseline + 2 * margin, :text_width + 2 * margin]
    banner[:] = banner // 3  # darken behind the label so it reads on any image
    origin = (margin, margin + text_height)
    cv2.putText(canvas, label, origin, cv2.FONT_HERSHEY_SIMPLEX, font_scale, (255, 255, 255), thickness, cv2.LINE_AA)
    return canvas


def _checked_rgb(pixels: np.ndarray, path: Path) -> np.ndarray:
    pixels = np.asarray(pixels)
    if pixels.dtype != np.uint8 or pixels.ndim != 3 or pixels.shape[2] != 3 or 0 in pixels.shape:
        raise ExportError(f"{path}: expected (H, W, 3) uint8 pixels, got {pixels.shape} {pixels.dtype}")
    return np.ascontiguousarray(pixels)
