"""Scene presets bundled in ``ringlight.resources.scenes``."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from .scene import Scene, SceneError, parse_scene, read_scene


def preset_names() -> list[str]:
    """Names of the bundled scene presets, sorted."""
    folder = resources.files("ringlight.resources.scenes")
    return sorted(item.name[:-5] for item in folder.iterdir() if item.name.endswith(".json"))


def _preset_document(name: str) -> dict:
    return json.loads(resources.files("ringlight.resources.scenes").joinpath(f"{name}.json").read_text())


def preset_notes(name: str) -> str:
    """The one-paragraph description stored in a preset."""
    return _preset_document(name).get("notes", "")


def load_scene(name_or_path: str, size: tuple[int, int] | None = None) -> Scene:
    """A preset by name, or a scene JSON file by path; ``size = (H, W)`` rescales the grid."""
    if name_or_path in preset_names():
        return parse_scene(_preset_document(name_or_path), where=f"preset {name_or_path}",
                           name=name_or_path, size=size)
    path = Path(name_or_path)
    if not path.exists() and path.suffix != ".json":
        raise SceneError(f"{name_or_path}: neither a preset ({', '.join(preset_names())}) nor a scene file")
    return read_scene(path, size=size)
