"""Checking every file a dataset references, cheaply, without decoding any pixels.

``ringlight info`` reports what :func:`check_files` finds, so that a truncated or missing frame is
known before a long open or stack, not halfway through one.
"""

from __future__ import annotations

from collections.abc import Callable

from ..errors import DatasetError
from .exr import check_exr
from .manifest import Manifest

_RGB = ("R", "G", "B")


def check_files(manifest: Manifest, allow_outside: bool = False,
                progress: Callable[[float], None] | None = None) -> list[str]:
    """Check the header of every file ``manifest`` references, in manifest order.

    Each file is checked as reading it would check it (see
    :func:`ringlight.core.dataset.exr.check_exr`): it resolves inside the dataset folder (unless
    ``allow_outside``), is a regular OpenEXR file, has the channels it needs (R, G, B; ``y`` and
    ``x`` for the mapping) at full resolution, has the size it must have (frames and dark: the
    grid, or the mapping's size in camera frame space; ground-truth images: the grid), and its
    chunk table fits the file (a truncated file fails this).

    Parameters
    ----------
    manifest
        A validated manifest.
    allow_outside
        Accept files that resolve outside the dataset folder through symbolic links.
    progress
        Called with the fraction of files checked, in [0, 1].

    Returns
    -------
    One line per problem, each naming its file; empty when every file passes.
    """
    problems: list[str] = []

    def check(name: str, channels: tuple[str, ...], shape, what: str, size_of: str | None):
        try:
            header = check_exr(manifest.file_path(name, allow_outside), channels, shape, what, size_of)
        except DatasetError as error:
            problems.append(str(error))
            return None
        return header.height, header.width

    frame_shape, size_of = (manifest.height, manifest.width), "the grid"
    if manifest.frame_space == "camera":
        # A broken mapping leaves the frames' size unknown: they are then checked for all else.
        frame_shape = check(manifest.mapping, ("y", "x"), None, "mapping", None)
        size_of = "the mapping"
    if manifest.dark is not None:
        check(manifest.dark, _RGB, frame_shape, "dark frame", size_of)
    truth = manifest.ground_truth.path_length_images if manifest.ground_truth else ()
    total = len(manifest.frames) + len(truth)
    for done, frame in enumerate(manifest.frames):
        check(frame.file, _RGB, frame_shape, "frame", size_of)
        if progress is not None and done % 256 == 255:
            progress((done + 1) / total)
    for image in truth:
        check(image.file, _RGB, (manifest.height, manifest.width), "ground-truth image", "the grid")
    if progress is not None:
        progress(1.0)
    return problems
