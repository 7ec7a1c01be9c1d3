"""Exporting and reading computed stacks (FORMAT.md "Stack export")."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..atomic import atomic_folder
from ..dataset.exr import read_exr_rgb, write_exr_rgb
from ..errors import DatasetError, StackError
from .stacks import Stack

STACK_FORMAT = "ringlight-stack"
STACK_VERSION = 1
STACK_MANIFEST = "stack.json"


def is_stack_folder(path: Path) -> bool:
    """True when ``path/stack.json`` declares the ringlight stack format."""
    try:
        return json.loads((Path(path) / STACK_MANIFEST).read_text(encoding="utf-8")).get("format") == STACK_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def write_stack(stack: Stack, folder, progress: Callable[[float], None] | None = None) -> Path:
    """Write ``stack`` as ``folder/stack.json`` plus one float EXR per radius, atomically.

    ``folder`` may be absent, an empty folder or an earlier stack export (replaced); anything
    else raises :class:`StackError` so that user data is never overwritten.
    """
    folder = Path(folder)
    if folder.exists() and not (
        (folder.is_dir() and not any(folder.iterdir())) or is_stack_folder(folder)
    ):
        raise StackError(f"{folder}: exists and is not a ringlight stack folder; refusing to overwrite it")
    prefix = "ring" if stack.kind == "ring" else "transient"
    names = [f"{prefix}_{index:03d}.exr" for index in range(len(stack.radii))]
    manifest = {
        "format": STACK_FORMAT, "version": STACK_VERSION, "kind": stack.kind,
        "radii": [float(r) for r in stack.radii], "thickness": stack.thickness,
        "step": stack.step, "colorspace": stack.colorspace,
        "images": names,
    }
    with atomic_folder(folder) as staging:
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
    manifest = json.loads(path.read_text(encoding="utf-8"))
    images = np.stack([read_exr_rgb(folder / name) for name in manifest["images"]])
    return manifest, images
