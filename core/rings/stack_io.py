"""Exporting and reading computed stacks (docs/format/stack.md)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..atomic import check_output_folder, output_folder
from ..colourspaces import colourspace_json
from ..dataset.exr import read_exr_rgb, write_exr_rgb
from ..errors import DatasetError
from ..ownership import Owned
from ..validation import read_json
from .coverage import RingCoverage, coverage_warning
from .stacks import Stack

STACK_FORMAT = "ringlight-stack"
STACK_VERSION = 1
STACK_MANIFEST = "stack.json"


def is_stack_folder(path: Path) -> bool:
    """True when ``path/stack.json`` declares the ringlight stack format."""
    return stack_files(Path(path)) is not None


def stack_files(folder: Path) -> Owned | None:
    """What an earlier stack export wrote in ``folder``: ``stack.json`` and the images it names;
    None when ``folder`` holds no ringlight stack manifest."""
    try:
        manifest = read_json(Path(folder) / STACK_MANIFEST, DatasetError, "stack manifest", max_bytes=2**24)
    except DatasetError:
        return None
    if not isinstance(manifest, dict) or manifest.get("format") != STACK_FORMAT:
        return None
    images = manifest.get("images")
    names = [name for name in images if isinstance(name, str)] if isinstance(images, list) else []
    return Owned(frozenset([STACK_MANIFEST, *names]))


def check_stack_target(folder) -> None:
    """Raise :class:`~ringlight.core.atomic.OutputError` unless :func:`write_stack` may write
    ``folder`` (call it before computing a stack, so that a refusal comes first)."""
    check_output_folder(folder, stack_files, "stack")


def write_stack(stack: Stack, folder, progress: Callable[[float], None] | None = None,
                coverage: RingCoverage | None = None) -> Path:
    """Write ``stack`` as ``folder/stack.json`` plus one float EXR per radius, atomically.

    With ``coverage`` (of the stack's rings), ``stack.json`` also holds its per-radius summary
    under ``"coverage"`` and, when coverage is poor, the warning line under ``"warnings"``.

    ``folder`` may be absent, an empty folder or an earlier stack export holding only the files
    its ``stack.json`` names (replaced whole); anything else raises
    :class:`~ringlight.core.atomic.OutputError` and nothing is touched (see
    :mod:`ringlight.core.atomic`).
    """
    folder = Path(folder)
    prefix = "ring" if stack.kind == "ring" else "transient"
    names = [f"{prefix}_{index:03d}.exr" for index in range(len(stack.radii))]
    manifest = {
        "format": STACK_FORMAT, "version": STACK_VERSION, "kind": stack.kind,
        "radii": [float(r) for r in stack.radii], "thickness": stack.thickness,
        "step": stack.step, "colorspace": colourspace_json(stack.colorspace),
        "images": names,
    }
    if coverage is not None:
        manifest["coverage"] = coverage.summary()
        warning = coverage_warning(coverage)
        manifest["warnings"] = [] if warning is None else [warning]
    with output_folder(folder, stack_files, "stack") as staging:
        for index, name in enumerate(names):
            write_exr_rgb(staging / name, stack.images[index])
            if progress is not None:
                progress((index + 1) / len(names))
        (staging / STACK_MANIFEST).write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    return folder


def read_stack(folder) -> tuple[dict, np.ndarray]:
    """Read a stack export: ``(manifest, images)`` with images (n, H, W, 3) float32."""
    folder = Path(folder)
    path = folder / STACK_MANIFEST
    if not is_stack_folder(folder):
        raise DatasetError(f"{path}: not a ringlight stack manifest")
    manifest = read_json(path, DatasetError, "stack manifest")
    names = manifest.get("images") if isinstance(manifest, dict) else None
    if not isinstance(names, list) or not names or not all(
            isinstance(name, str) and name and "/" not in name and name not in (".", "..") for name in names):
        raise DatasetError(f"{path}: 'images' must be a non-empty list of file names in the stack folder")
    images = []
    for name in names:
        image = read_exr_rgb(folder / name)
        if images and image.shape != images[0].shape:
            raise DatasetError(f"{folder / name}: {image.shape[1]} x {image.shape[0]} pixels, where the stack's "
                               f"first image, {names[0]}, has {images[0].shape[1]} x {images[0].shape[0]}")
        images.append(image)
    return manifest, np.stack(images)
