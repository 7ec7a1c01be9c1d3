"""Rendering a scene into an impulse dataset with path-length ground truth.

Every grid point is lit with ``photons_per_point`` photons per colour channel (one pass for grey
scenes). Impulse frames keep each lit point's light within ``max_radius`` (the part a parallel
capture attributes to it: frames are crosstalk-free) and are multiplexed on a lattice of spacing
``floor(2 * max_radius) + 1`` when that needs fewer frames than one point per frame. Values are
the scene's measure (FORMAT.md "What a simulated frame holds"): by default the reflectance
factor toward the camera, else the exitance, per unit beam power. The specular reflection at
the surface is in neither the frames nor the path-length images; the manifest's notes state it,
and the measure, as a line ``measure: camera`` (or ``exitance``): see :func:`simulated_measure`.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataset.impulse_dataset import ProgressCallback, disc_offsets
from ..dataset.manifest import Manifest
from ..dataset.writer import DatasetWriter
from . import photon
from .adding_doubling import thick_slab_reflectance
from .camera import UNIFORM_MU_T, column_optical_depths, optics, specular_reflectance
from .lattice import lattice_frames
from .reference import (
    KERNEL_STREAMS,
    mixed_columns,
    reference_kernel,
    reference_optics,
    reference_volume,
    simulate_point_differences,
    spread_kernel,
)
from .scene import Material, Scene

TRUTH_BLOCKS = 16
POINTS_PER_CALL = 64
KERNEL_SHARE = 0.25
"""With the reference estimator in a scene that differs from its reference, the kernel's
photons as a fraction of all lit points' (measured on red-bead: the differences dominate the noise)."""
SIMULATED_PREFIX = "simulated by ringlight"
MEASURE_NOTE = re.compile(r"^measure: (camera|exitance)$", re.MULTILINE)


@dataclass(frozen=True, eq=False)
class Transport:
    """Simulated light transport of a scene (every grid point lit unless told otherwise).

    Attributes
    ----------
    windows
        (H, W, 2R+1, 2R+1, 3) float32: the measure (reflectance factor or exitance per unit
        beam power) around each lit point ``[y, x]``, at offset ``[dy + R, dx + R]`` of the
        pixel where light leaves (R = ceil(max_radius)).
    path_length_images
        (bins, H, W, 3) float32: the same under uniform illumination of the whole grid (every
        grid point's beam), by path-length bin ``[b * step, (b + 1) * step)``.
    measure
        ``"camera"`` or ``"exitance"``, the scene's.
    """

    scene: Scene
    photons: int
    seed: int
    window_radius: int
    windows: np.ndarray
    path_length_images: np.ndarray
    seconds: float
    measure: str = "camera"
    estimator: str = "reference"


def _channel_tables(materials: tuple[Material, ...], channel: int):
    mu_t = np.array([m.mus[channel] + m.mua[channel] for m in materials])
    albedo = np.array([m.mus[channel] / t if t > 0 else 0.0 for m, t in zip(materials, mu_t)])
    g = np.array([m.g for m in materials])
    return mu_t, albedo, g


ESTIMATORS = ("reference", "analogue")
"""``reference``: a shift-invariant reference plus correlated differences
(:mod:`.reference`, the default); ``analogue``: every lit point's photons walk on their own."""


def simulate_transport(scene: Scene, photons: int | None = None, seed: int | None = None,
                       progress: ProgressCallback | None = None, points: np.ndarray | None = None,
                       estimator: str = "reference") -> Transport:
    """Trace photons from every grid point of ``scene``; see :class:`Transport`.

    ``points`` (n, 2) ``[y, x]`` restricts the lit points (their windows alone are filled, and
    the path-length images are then those of lighting just these points). ``estimator`` is one
    of :data:`ESTIMATORS`; both give the same expectations. With ``reference``, the reference
    kernel gets ``photons`` times the number of lit points, and each lit point ``photons``
    correlated walks where the scene differs from the reference (none in a layered scene).
    Deterministic for a seed whatever the number of threads: each point's random stream depends
    on the seed and its row-major grid index only. ``progress`` gets the fraction done and may
    raise :class:`Cancelled`.
    """
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    photons = photons or scene.photons_per_point
    seed = scene.seed if seed is None else seed
    height, width = scene.height, scene.width
    radius = math.ceil(scene.max_radius)
    size = 2 * radius + 1
    if points is None:
        lit = np.stack(np.mgrid[:height, :width], -1).reshape(-1, 2).astype(np.int64)
    else:
        lit = np.asarray(points, np.int64).reshape(-1, 2)
    streams = lit[:, 0] * width + lit[:, 1]
    channels = (0,) if scene.grey else (0, 1, 2)
    windows = np.zeros((height * width, size, size, 3), np.float64)
    truth = np.zeros((scene.bin_count, height, width, 3), np.float64)
    started = time.perf_counter()
    work = _reference_work if estimator == "reference" else _analogue_work
    steps = list(work(scene, photons, seed, lit, streams, channels, windows, truth))
    for done, step in enumerate(steps):
        step()
        if progress is not None:
            progress((done + 1) / len(steps))
    if scene.grey:
        windows[..., 1:] = windows[..., :1]
        truth[..., 1:] = truth[..., :1]
    return Transport(
        scene=scene, photons=photons, seed=seed, window_radius=radius,
        windows=windows.reshape(height, width, size, size, 3).astype(np.float32),
        path_length_images=truth.astype(np.float32), seconds=time.perf_counter() - started,
        measure=scene.measure, estimator=estimator,
    )


def _channel_setup(scene: Scene, channel: int, volume: np.ndarray):
    """``(tables, majorant, optics)`` of one channel for the materials used in ``volume``."""
    tables = _channel_tables(scene.materials, channel)
    used = np.unique(volume)
    mu_t = tables[0]
    majorant = float(mu_t[used].max())
    uniform_mu_t = majorant if mu_t[used].min() == majorant else -1.0
    return tables, majorant, optics(scene.n, scene.depth, scene.projector, scene.camera, uniform_mu_t)


def _analogue_work(scene, photons, seed, lit, streams, channels, windows, truth):
    """Steps (callables) of the analogue estimator: every lit point's photons on their own."""
    height, width = scene.height, scene.width
    camera = scene.measure == "camera"
    size = windows.shape[1]

    def chunk_step(channel, start):
        def step():
            tables, majorant, geometry = _channel_setup(scene, channel, scene.volume)
            columns = (column_optical_depths(scene.volume, tables[0], scene.camera)
                       if camera and geometry[UNIFORM_MU_T] < 0 else np.zeros((0, 0, 0)))
            chunk = lit[start:start + POINTS_PER_CALL]
            chunk_windows = np.zeros((len(chunk), size, size))
            chunk_truth = np.zeros((min(TRUTH_BLOCKS, len(chunk)), scene.bin_count, height, width))
            photon.simulate_points(
                scene.volume, *tables, majorant, geometry, columns, camera, chunk, photons, seed,
                streams[start:start + POINTS_PER_CALL] + channel * height * width,
                scene.bin_step, chunk_windows, chunk_truth,
            )
            windows[streams[start:start + len(chunk)], :, :, channel] = chunk_windows / photons
            truth[..., channel] += chunk_truth.sum(axis=0) / photons
        return step

    for channel in channels:
        for start in range(0, len(lit), POINTS_PER_CALL):
            yield chunk_step(channel, start)


def _reference_work(scene, photons, seed, lit, streams, channels, windows, truth):
    """Steps (callables) of the reference estimator (:mod:`.reference`): per channel, the
    reference kernel spread to every lit point, then the correlated differences."""
    height, width = scene.height, scene.width
    camera = scene.measure == "camera"
    size = windows.shape[1]
    base = reference_volume(scene.volume)
    mixed = mixed_columns(scene.volume, base, scene.n, scene.camera)
    # A walk can reach any column: every lit point needs its differences once one differs.
    differing = np.arange(len(lit)) if mixed.any() else np.zeros(0, np.int64)
    symmetric = scene.camera[0] == 0.0 and scene.projector[0] == 0.0
    # Kernel streams sit above every point's walk streams.
    kernel_stream = 3 * height * width
    kernel_photons = photons * len(lit) if len(differing) == 0 else max(1, int(photons * len(lit) * KERNEL_SHARE))

    def kernel_step(channel):
        def step():
            tables, majorant, geometry = _channel_setup(scene, channel, scene.volume)
            base_geometry = reference_optics(scene.n, scene.depth, scene.projector, scene.camera, tables[0], base)
            window, kernel = reference_kernel(
                base, tables, majorant, base_geometry, camera, scene.camera, kernel_photons, seed,
                kernel_stream + channel * KERNEL_STREAMS, size // 2, (height, width), scene.bin_step,
                scene.bin_count, symmetric)
            windows[streams, :, :, channel] += window
            truth[..., channel] += spread_kernel(kernel, lit, (height, width))
        return step

    def difference_step(channel, start):
        def step():
            tables, majorant, geometry = _channel_setup(scene, channel, scene.volume)
            base_geometry = reference_optics(scene.n, scene.depth, scene.projector, scene.camera, tables[0], base)
            chosen = differing[start:start + POINTS_PER_CALL]
            chunk = lit[chosen]
            chunk_windows = np.zeros((len(chunk), size, size))
            chunk_truth = np.zeros((min(TRUTH_BLOCKS, len(chunk)), scene.bin_count, height, width))
            simulate_point_differences(
                scene.volume, base, mixed, tables, majorant, geometry, base_geometry, camera, scene.camera, chunk,
                photons, seed, streams[chosen] + channel * height * width, scene.bin_step, chunk_windows, chunk_truth)
            windows[streams[chosen], :, :, channel] += chunk_windows / photons
            truth[..., channel] += chunk_truth.sum(axis=0) / photons
        return step

    for channel in channels:
        yield kernel_step(channel)
        for start in range(0, len(differing), POINTS_PER_CALL):
            yield difference_step(channel, start)


def slab_reflectance(material: Material, n: float) -> np.ndarray:
    """Diffuse reflectance (R, G, B) of a semi-infinite slab of ``material`` under index ``n``
    at normal incidence, per unit incident power, specular excluded: a layer's reference colour
    (FORMAT.md), exact by adding-doubling (:mod:`.adding_doubling`), not a Monte Carlo estimate."""
    return thick_slab_reflectance(material.mus, material.mua, material.g, n)


def write_transport(transport: Transport, out, *, overwrite: bool = False,
                    progress: Callable[[float], None] | None = None) -> Path:
    """Write a :class:`Transport` as a FORMAT.md dataset (atomically)."""
    scene = transport.scene
    height, width = scene.height, scene.width
    radius = transport.window_radius
    offsets = disc_offsets(scene.max_radius)
    frames = lattice_frames(height, width, scene.max_radius)
    notes = (f"{SIMULATED_PREFIX} from scene '{scene.name}': {transport.photons} photons per point "
             f"per channel, seed {transport.seed}, n {scene.n:g}\n"
             f"measure: {transport.measure}\n"
             f"camera direction {list(scene.camera)}, projector direction {list(scene.projector)} "
             f"([zenith, azimuth] degrees)\n"
             f"specular reflection {specular_reflectance(scene.n, scene.projector[0]):.6g} of the beam, "
             f"not in the frames or path-length images")
    with DatasetWriter(out, (height, width), max_radius=scene.max_radius, pitch_mm=scene.pitch_mm,
                       notes=notes, overwrite=overwrite) as writer:
        for index, lit in enumerate(frames):
            image = np.zeros((height, width, 3), np.float32)
            for qy, qx in lit:
                py, px = qy + offsets[:, 0], qx + offsets[:, 1]
                inside = (py >= 0) & (py < height) & (px >= 0) & (px < width)
                image[py[inside], px[inside]] += transport.windows[
                    qy, qx, offsets[inside, 0] + radius, offsets[inside, 1] + radius]
            writer.add_frame(image, lit)
            if progress is not None:
                progress((index + 1) / (len(frames) + 1))
        for b, image in enumerate(transport.path_length_images):
            writer.add_path_length_image(image, b * scene.bin_step, (b + 1) * scene.bin_step)
        if scene.layers:
            writer.set_layers([
                {"name": name, "depth": [top, bottom],
                 "rgb": slab_reflectance(scene.material(name), scene.n).tolist()}
                for name, top, bottom in scene.layers
            ])
    if progress is not None:
        progress(1.0)
    return Path(out)


def simulated_measure(manifest: Manifest) -> str | None:
    """What a dataset's frames hold if ringlight simulated it: ``"camera"`` (the reflectance
    factor toward the camera), ``"exitance"`` (datasets simulated before the camera measure
    carry no ``measure:`` line and hold exitance, with the specular reflection added at the lit
    pixel), or None when ringlight did not simulate it (a capture, another tool)."""
    notes = manifest.notes or ""
    if manifest.ground_truth is None or not notes.startswith(SIMULATED_PREFIX):
        return None
    marker = MEASURE_NOTE.search(notes)
    return marker.group(1) if marker else "exitance"


def simulated_before_camera_measure(manifest: Manifest) -> bool:
    """True for a dataset ringlight simulated before frames held camera radiance: it has no
    ``measure:`` line and holds exitance plus the specular reflection at the lit pixel (one
    simulated with ``measure: exitance`` on purpose says so and is not flagged)."""
    notes = manifest.notes or ""
    return simulated_measure(manifest) == "exitance" and MEASURE_NOTE.search(notes) is None
