"""Scene descriptions for the Monte Carlo simulator (docs/format/scene.md, version 1).

A scene is a voxel volume below a flat surface: ``depth`` grid steps deep, one voxel per grid
step laterally and in depth, each voxel holding one material. The volume extends sideways
beyond the grid by repeating its edge voxels (a sample is larger than the scanned region).
Coefficients are per grid step, or per mm when ``grid.pitch_mm`` is given (converted here).
The optional ``camera``, ``projector`` (``{"direction": [zenith, azimuth]}`` in degrees, a
direction of travel: zenith from straight down, azimuth from +x toward +y) and ``measure``
(``"camera"`` or ``"exitance"``) say what a frame holds (docs/format/scene.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RinglightError
from ..validation import Validator, read_json

SCENE_FORMAT = "ringlight-scene"
SCENE_VERSION = 1
MAX_VOXELS = 64 * 2**20
MEASURES = ("camera", "exitance")
MAX_ZENITH = 89.0
"""Degrees: a camera or projector farther from straight down is refused (grazing light)."""
MAX_COEFFICIENT = 1000.0
"""Largest scattering or absorption coefficient per grid step: a mean free path of a thousandth
of a grid step, far below what the grid resolves. Beyond it a walk takes steps that no longer
move it (mus 1e308 spun in the reference kernel for good, ignoring Ctrl+C)."""
MAX_LAYERS = 256
"""Most ``layers`` a scene may list (20 000 ran for minutes before a photon was traced)."""
MAX_SHAPES = 256
"""Most ``shapes`` a scene may list: each is drawn over the whole volume."""
MAX_STAR_POINTS = 360
"""Most tips of a star (the mask costs one pass over the grid per edge: a huge ``points`` took
46 s of CPU before any photon)."""
MAX_SIMULATION_BYTES = 16 * 2**30
"""Most memory a simulation's arrays may take (:func:`simulation_bytes`): a ``max_radius`` or
``path_length_bins.count`` asking for more (3 PiB, 805 GiB) is refused before any allocation."""


class SceneError(RinglightError):
    """A scene description is malformed or asks for more than can be simulated."""


@dataclass(frozen=True)
class Material:
    """Scattering and absorption coefficients per grid step (R, G, B) and HG anisotropy."""

    name: str
    mus: tuple[float, float, float]
    mua: tuple[float, float, float]
    g: float


@dataclass(frozen=True, eq=False)
class Scene:
    """A parsed, voxelised scene.

    Attributes
    ----------
    volume
        (D, H, W) uint8 material index of each voxel; voxel ``[z, y, x]`` spans depth
        ``[z, z + 1)`` below the surface and is centred laterally on grid point ``[y, x]``.
    materials
        The materials, indexed by ``volume``; coefficients per grid step.
    camera, projector
        ``[zenith, azimuth]`` in degrees of the camera's viewing direction and of the beam's
        direction of incidence (0 = straight down; azimuth from +x toward +y).
    measure
        ``"camera"`` (the reflectance factor toward the camera) or ``"exitance"`` (all light
        leaving a pixel, for comparisons with MCML-style tables); docs/format/scene.md.
    """

    name: str
    height: int
    width: int
    pitch_mm: float | None
    depth: float
    n: float
    materials: tuple[Material, ...]
    volume: np.ndarray
    layers: tuple[tuple[str, float, float], ...]
    photons_per_point: int
    max_radius: float
    bin_step: float
    bin_count: int
    seed: int
    camera: tuple[float, float] = (0.0, 0.0)
    projector: tuple[float, float] = (0.0, 0.0)
    measure: str = "camera"

    @property
    def grey(self) -> bool:
        """True when every material has the same coefficients in all three channels."""
        return all(len(set(m.mus)) == 1 and len(set(m.mua)) == 1 for m in self.materials)

    def material(self, name: str) -> Material:
        return next(m for m in self.materials if m.name == name)


def read_scene(path: str | Path, size: tuple[int, int] | None = None) -> Scene:
    """Read and validate a scene JSON file (``size`` as in :func:`parse_scene`); raises
    :class:`SceneError` naming the file."""
    path = Path(path)
    document = read_json(path, SceneError, "scene file")
    return parse_scene(document, where=str(path), name=path.stem, size=size)


def parse_scene(document: object, where: str = "scene", name: str = "scene",
                size: tuple[int, int] | None = None) -> Scene:
    """Validate a decoded scene and voxelise it.

    ``size = (H, W)`` overrides the grid size; shapes then scale with the grid's width and
    height (positions and lateral sizes), so a preset can be rendered smaller or larger.
    """
    fail = Validator(where, SceneError)
    doc = fail.mapping(document, "scene", {
        "format", "version", "grid", "depth", "n", "materials", "background", "layers", "shapes",
        "photons_per_point", "max_radius", "path_length_bins", "seed", "notes", "camera", "projector", "measure",
    }, {"format", "version", "grid", "depth", "materials", "background"})
    if doc["format"] != SCENE_FORMAT:
        raise SceneError(f"{where}: 'format' is {doc['format']!r}, expected {SCENE_FORMAT!r}")
    if doc["version"] != SCENE_VERSION or isinstance(doc["version"], bool):  # true == 1 in Python
        raise SceneError(f"{where}: unsupported 'version' {doc['version']!r} (expected {SCENE_VERSION})")
    if "notes" in doc:
        fail.string(doc["notes"], "notes")
    grid = fail.mapping(doc["grid"], "grid", {"height", "width", "pitch_mm"}, {"height", "width"})
    height, width = fail.positive_int(grid["height"], "grid.height"), fail.positive_int(grid["width"], "grid.width")
    scale_y = scale_x = 1.0
    if size is not None:
        scale_y, scale_x = size[0] / height, size[1] / width
        height, width = size
    pitch_mm = fail.positive_number(grid["pitch_mm"], "grid.pitch_mm") if "pitch_mm" in grid else None
    per_step = pitch_mm if pitch_mm is not None else 1.0
    depth = fail.positive_number(doc["depth"], "depth")
    n = fail.number(doc.get("n", 1.0), "n")
    if not 1.0 <= n <= 3.0:
        raise SceneError(f"{where}: refractive index 'n' must be in [1, 3], got {n}")

    materials, index = [], {}
    for material_name, spec in fail.mapping(doc["materials"], "materials", None, set()).items():
        key = f"materials.{material_name}"
        item = fail.mapping(spec, key, {"mus", "mua", "g"}, {"mus", "mua"})
        mus = _rgb(fail, item["mus"], f"{key}.mus")
        mua = _rgb(fail, item["mua"], f"{key}.mua")
        g = fail.number(item.get("g", 0.0), f"{key}.g")
        if not -1.0 < g < 1.0:
            raise SceneError(f"{where}: '{key}.g' must be in (-1, 1), got {g}")
        if max(m + a for m, a in zip(mus, mua)) * per_step <= 0:
            raise SceneError(f"{where}: '{key}' neither scatters nor absorbs")
        index[material_name] = len(materials)
        materials.append(Material(material_name, tuple(v * per_step for v in mus),
                                  tuple(v * per_step for v in mua), g))
    for material in materials:
        for kind in ("mus", "mua"):
            if max(getattr(material, kind)) > MAX_COEFFICIENT:
                raise SceneError(
                    f"{where}: 'materials.{material.name}.{kind}' is {max(getattr(material, kind)):g} per grid step, "
                    f"more than {MAX_COEFFICIENT:g} (a mean free path of 1/{MAX_COEFFICIENT:g} grid step)")
    if not materials:
        raise SceneError(f"{where}: 'materials' is empty")
    if len(materials) > 255:
        raise SceneError(f"{where}: at most 255 materials")

    def material_index(value, key):
        name_ = fail.string(value, key)
        if name_ not in index:
            raise SceneError(f"{where}: '{key}' names unknown material {name_!r} (known: {', '.join(index)})")
        return index[name_]

    voxels = height * width * math.ceil(depth)
    if voxels > MAX_VOXELS:
        raise SceneError(
            f"{where}: the volume {height} x {width} x {math.ceil(depth)} has {voxels} voxels, more than "
            f"the {MAX_VOXELS} that fit in memory; make the grid smaller or the depth shallower"
        )
    photons = fail.positive_int(doc.get("photons_per_point", 20000), "photons_per_point")
    max_radius = fail.positive_number(doc.get("max_radius", 16), "max_radius")
    bins = fail.mapping(doc.get("path_length_bins", {"step": 1.0, "count": 64}), "path_length_bins",
                        {"step", "count"}, {"step", "count"})
    bin_count = fail.positive_int(bins["count"], "path_length_bins.count")
    needed = simulation_bytes(height, width, max_radius, bin_count)
    if needed > MAX_SIMULATION_BYTES:  # before the volume, or anything of the grid's size, is made
        raise SceneError(
            f"{where}: simulating it would take {_gibibytes(needed)} (grid {height} x {width}, max_radius "
            f"{max_radius:g}, path_length_bins.count {bin_count}), more than {MAX_SIMULATION_BYTES // 2**30} GiB; "
            "make the grid, max_radius or path_length_bins.count smaller")
    volume = np.full((math.ceil(depth), height, width), material_index(doc["background"], "background"), np.uint8)
    z = np.arange(volume.shape[0]) + 0.5
    layers = []
    for key, limit in (("layers", MAX_LAYERS), ("shapes", MAX_SHAPES)):
        if len(fail.sequence(doc.get(key, []), key)) > limit:
            raise SceneError(f"{where}: '{key}' lists {len(doc[key])} entries, at most {limit}")
    for i, entry in enumerate(fail.sequence(doc.get("layers", []), "layers")):
        key = f"layers[{i}]"
        item = fail.mapping(entry, key, {"material", "top", "bottom"}, {"material", "top", "bottom"})
        top, bottom = fail.number(item["top"], f"{key}.top"), fail.number(item["bottom"], f"{key}.bottom")
        if not 0 <= top < bottom <= depth:
            raise SceneError(f"{where}: '{key}' needs 0 <= top < bottom <= depth ({depth:g}), got [{top}, {bottom}]")
        volume[(z >= top) & (z < bottom)] = material_index(item["material"], f"{key}.material")
        layers.append((item["material"], top, bottom))
    deepest = max((bottom for _, _, bottom in layers), default=depth)
    if deepest < depth:  # the background under the listed layers is the deepest layer
        layers.append((doc["background"], deepest, depth))
    yy, xx = np.arange(height, dtype=np.float64)[:, None], np.arange(width, dtype=np.float64)[None, :]
    for i, entry in enumerate(fail.sequence(doc.get("shapes", []), "shapes")):
        key = f"shapes[{i}]"
        kind = fail.mapping(entry, key, None, {"type", "material"})["type"]
        material = material_index(entry["material"], f"{key}.material")
        if kind == "sphere":
            item = fail.mapping(entry, key, {"type", "material", "center", "radius"}, {"center", "radius"})
            cy, cx, cz = fail.numbers(item["center"], f"{key}.center", 3)
            radius = fail.positive_number(item["radius"], f"{key}.radius")
            cy, cx = cy * scale_y, cx * scale_x
            if not (0 <= cy < height and 0 <= cx < width and 0 <= cz < depth):
                raise SceneError(f"{where}: '{key}' centre [{cy:g}, {cx:g}, {cz:g}] is outside the volume")
            lateral = (yy - cy) ** 2 + (xx - cx) ** 2  # one (H, W) plane at a time, not (D, H, W)
            for slab in np.nonzero(np.abs(z - cz) <= radius)[0]:
                volume[slab][lateral + (z[slab] - cz) ** 2 <= radius**2] = material
        elif kind == "star":
            item = fail.mapping(entry, key, {"type", "material", "center", "top", "bottom", "points", "outer", "inner"},
                                {"center", "top", "bottom", "points", "outer", "inner"})
            cy, cx = fail.numbers(item["center"], f"{key}.center", 2)
            cy, cx = cy * scale_y, cx * scale_x
            top, bottom = fail.number(item["top"], f"{key}.top"), fail.number(item["bottom"], f"{key}.bottom")
            points = fail.positive_int(item["points"], f"{key}.points")
            outer, inner = fail.positive_number(item["outer"], f"{key}.outer"), fail.positive_number(item["inner"], f"{key}.inner")
            if not (0 <= cy < height and 0 <= cx < width) or not 0 <= top < bottom <= depth:
                raise SceneError(f"{where}: '{key}' lies outside the volume")
            if not 2 <= points <= MAX_STAR_POINTS or inner >= outer:
                raise SceneError(f"{where}: '{key}' needs 2 <= points <= {MAX_STAR_POINTS} and inner < outer")
            mask = star_mask(height, width, cy, cx, points, outer * scale_x, inner * scale_x)
            volume[((z >= top) & (z < bottom))[:, None, None] & mask[None]] = material
        else:
            raise SceneError(f"{where}: '{key}.type' must be \"sphere\" or \"star\", got {kind!r}")

    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SceneError(f"{where}: 'seed' must be a non-negative integer, got {seed!r}")
    camera = _direction(fail, doc.get("camera", {"direction": [0, 0]}), "camera")
    projector = _direction(fail, doc.get("projector", {"direction": [0, 0]}), "projector")
    measure = fail.string(doc.get("measure", "camera"), "measure")
    if measure not in MEASURES:
        raise fail.fail("measure", " or ".join(map(repr, MEASURES)), measure)
    return Scene(
        name=name, height=height, width=width, pitch_mm=pitch_mm, depth=depth, n=n,
        materials=tuple(materials), volume=volume, layers=tuple(layers), photons_per_point=photons,
        max_radius=max_radius, bin_step=fail.positive_number(bins["step"], "path_length_bins.step"),
        bin_count=bin_count, seed=seed, camera=camera, projector=projector, measure=measure,
    )


def _gibibytes(count: int) -> str:
    """``count`` bytes in GiB, for a message (a max_radius of 1e308 asks for more than a float holds)."""
    return f"{count / 2**30:,.0f} GiB" if count < 2**100 else "over 2^70 GiB"


def simulation_bytes(height: int, width: int, max_radius: float, bin_count: int) -> int:
    """Bytes of the float64 arrays a simulation holds at once (Python integers: no overflow):
    the (H, W, 2R+1, 2R+1, 3) windows with R = ceil(max_radius) and a call's worth of them, and
    per path-length bin the (H, W, 3) images, 16 blocks of a call's images and 16 of the
    reference kernel's (2H-1, 2W-1, 3) (:mod:`.transport`, :mod:`.reference`)."""
    size = 2 * math.ceil(max_radius) + 1
    points = height * width
    per_bin = points + 16 * points + 16 * (2 * height - 1) * (2 * width - 1)
    return 8 * 3 * ((points + 64) * size * size + bin_count * per_bin)


def star_mask(height: int, width: int, cy: float, cx: float, points: int, outer: float, inner: float) -> np.ndarray:
    """(H, W) bool: grid points inside a star polygon of ``points`` tips (even-odd rule)."""
    angles = np.pi * np.arange(2 * points) / points - np.pi / 2
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    vy, vx = cy + radii * np.sin(angles), cx + radii * np.cos(angles)
    yy, xx = np.arange(height, dtype=np.float64)[:, None], np.arange(width, dtype=np.float64)[None, :]
    inside = np.zeros((height, width), bool)
    for i in range(len(vy)):
        y0, x0, y1, x1 = vy[i - 1], vx[i - 1], vy[i], vx[i]
        crosses = (y0 > yy) != (y1 > yy)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = x0 + (yy - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (xx < at)
    return inside


def _rgb(check: Validator, value: object, key: str) -> tuple[float, float, float]:
    values = check.numbers(value, key, 3)
    if min(values) < 0:
        raise SceneError(f"{check.where}: '{key}' has a negative coefficient {list(values)}")
    return values


def _direction(check: Validator, value: object, key: str) -> tuple[float, float]:
    """``{"direction": [zenith, azimuth]}`` in degrees, zenith in [0, MAX_ZENITH]."""
    item = check.mapping(value, key, {"direction"}, {"direction"})
    zenith, azimuth = check.numbers(item["direction"], f"{key}.direction", 2)
    if not 0.0 <= zenith <= MAX_ZENITH:
        raise check.fail(f"{key}.direction", f"[zenith, azimuth] in degrees with zenith in [0, {MAX_ZENITH:g}]",
                         item["direction"])
    return zenith, azimuth
