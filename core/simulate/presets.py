"""Scene presets bundled in ``ringlight.resources.scenes`` and the demo dataset."""

from __future__ import annotations

import json
from dataclasses import replace
from importlib import resources
from pathlib import Path

from ..dataset.cache import user_cache_root
from .scene import Scene, SceneError, parse_scene, read_scene

DEMO_PRESET = "red-bead"
DEMO_SIZE = (32, 32)
DEMO_PHOTONS = 1500
DEMO_MEASURE = "camera"


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


def demo_dataset_path() -> Path:
    """Where the demo dataset lives (made on first use by :func:`ensure_demo_dataset`); the name
    carries the measure, so that a demo made before the camera measure (exitance) is not reused."""
    return user_cache_root() / f"demo-{DEMO_PRESET}-{DEMO_SIZE[0]}x{DEMO_SIZE[1]}-{DEMO_PHOTONS}-{DEMO_MEASURE}"


def ensure_demo_dataset(progress=None) -> Path:
    """Make the demo dataset (the red-bead preset at 32 x 32, 1500 photons per point, seed 0,
    the camera measure) in the user cache folder if it is not there yet; returns its folder."""
    from ..dataset.writer import is_dataset_folder
    from .transport import simulate_transport, write_transport

    path = demo_dataset_path()
    if not is_dataset_folder(path):
        scene = replace(load_scene(DEMO_PRESET, size=DEMO_SIZE), measure=DEMO_MEASURE)
        transport = simulate_transport(scene, photons=DEMO_PHOTONS, progress=progress)
        write_transport(transport, path, overwrite=True)
    return path
