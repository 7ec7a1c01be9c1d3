"""Rendering a scene into an impulse dataset with path-length ground truth.

Every grid point is lit with ``photons_per_point`` photons for each group of colour channels
that scatter alike (:func:`channel_groups`: one group for grey scenes and every preset; each walk
carries a weight per channel, :mod:`.tables`). Impulse frames keep each lit point's light within ``max_radius`` (the part a parallel
capture attributes to it: frames are crosstalk-free) and are multiplexed on a lattice of spacing
``floor(2 * max_radius) + 1`` when that needs fewer frames than one point per frame. Values are
the scene's measure (docs/format/scene.md, "What a simulated frame holds"): by default the reflectance
factor toward the camera, else the exitance, per unit beam power. The specular reflection at
the surface is in neither the frames nor the path-length images; the manifest's notes state it,
and the measure, as a line ``measure: camera`` (or ``exitance``): see :func:`simulated_measure`.
"""

from __future__ import annotations

import functools
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataset.disc import disc_offsets
from ..device import Device, cpu_device
from ..dataset.impulse_dataset import ProgressCallback
from ..dataset.manifest import Manifest
from ..dataset.sample import Sample
from ..dataset.writer import DatasetWriter
from .adding_doubling import thick_slab_reflectance
from .allocation import PILOT_PHOTONS, allocate, reach_fractions
from .camera import UNIFORM_MU_T, column_optical_depths, optics, specular_reflectance
from .lattice import lattice_frames
from .photon import point_kernels
from .reference import (
    KERNEL_STREAMS,
    mixed_voxels,
    reference_kernel,
    reference_optics,
    reference_volume,
    simulate_point_differences,
    spread_kernel,
)
from .scene import Material, Scene
from .tables import MU_T, walk_tables

TRUTH_BLOCKS = 16
POINTS_PER_CALL = 64
POINTS_PER_CUDA_CALL = 1 << 14
"""Lit points per kernel launch on a GPU (one thread each)."""
CUDA_KERNEL_STREAMS = 1 << 14
"""The reference kernel's random streams on a GPU (one thread each; the CPU's are
:data:`.reference.KERNEL_STREAMS`), numbered from :data:`CUDA_KERNEL_STREAM_BASE`, above every
stream a CPU run names and below the estimators' (:data:`.streams.ESTIMATOR_STREAM`)."""
CUDA_KERNEL_STREAM_BASE = 1 << 39
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
    replicates
        Windows (each as ``windows``) of independent runs whose mean ``windows`` is
        (:mod:`ringlight.core.simulate.replicates`), or empty: written as the dataset's replicates (the frame key
        ``replicate``), so that its noise, shared by lit points or not, can be measured.
    device
        The name of the device that traced the photons (:attr:`ringlight.core.device.Device.name`).
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
    replicates: tuple[np.ndarray, ...] = ()
    device: str = "CPU"


def channel_groups(scene: Scene) -> list[tuple[int, ...]]:
    """The scene's channels grouped by what walks they can share (:mod:`.tables`): channels
    whose materials all scatter alike (the same ``mus``; ``g`` is one per material)."""
    groups: dict[tuple[float, ...], list[int]] = {}
    for channel in (0,) if scene.grey else (0, 1, 2):
        groups.setdefault(tuple(m.mus[channel] for m in scene.materials), []).append(channel)
    return [tuple(group) for group in groups.values()]


ESTIMATORS = ("reference", "analogue")
"""``reference``: a shift-invariant reference plus correlated differences
(:mod:`.reference`, the default); ``analogue``: every lit point's photons walk on their own."""


def simulate_transport(scene: Scene, photons: int | None = None, seed: int | None = None,
                       progress: ProgressCallback | None = None, points: np.ndarray | None = None,
                       estimator: str = "reference", device: Device | None = None) -> Transport:
    """Trace photons from every grid point of ``scene``; see :class:`Transport`.

    ``points`` (n, 2) ``[y, x]`` restricts the lit points (their windows alone are filled, and
    the path-length images are then those of lighting just these points). ``estimator`` is one
    of :data:`ESTIMATORS`; both give the same expectations. With ``reference``, the reference
    kernel gets ``photons`` times the number of lit points (a quarter of that when the scene
    differs from the reference), and the lit points ``photons`` correlated walks each on average,
    shared by how often their walks reach where the scene differs (:mod:`.allocation`; none in a
    layered scene).
    Deterministic for a seed whatever the number of threads: each point's random stream depends
    on the seed and its row-major grid index only. ``progress`` gets the fraction done and may
    raise :class:`Cancelled`. ``device`` runs the walks (the CPU when None): on a GPU
    (:mod:`.photon_cuda`) each lit point walks the same streams, but the reference kernel's
    photons are shared among :data:`CUDA_KERNEL_STREAMS` streams, so that a GPU run is another
    sample of the CPU's; the allocation's pilot runs on the CPU either way.
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
    # Only the lit points' windows are summed in float64 (``row_of``: each point's row there): a
    # run of a few points on a large grid zeroed and converted every point's (160 MB at 51 x 51
    # and max_radius 25, 0.4 s a run).
    rows, row_of = np.unique(streams, return_inverse=True)
    groups = channel_groups(scene)
    windows = np.zeros((len(rows), size, size, 3), np.float64)
    truth = np.zeros((scene.bin_count, height, width, 3), np.float64)
    started = time.perf_counter()
    device = device or cpu_device()
    work = _reference_work if estimator == "reference" else _analogue_work
    steps = list(work(scene, photons, seed, lit, streams, row_of, groups, windows, truth, device))
    for done, step in enumerate(steps):
        step()
        if progress is not None:
            progress((done + 1) / len(steps))
    if scene.grey:
        windows[..., 1:] = windows[..., :1]
        truth[..., 1:] = truth[..., :1]
    # np.zeros maps its pages as they are written: the unlit points' rows cost no work.
    every_window = np.zeros((height * width, size, size, 3), np.float32)
    every_window[rows] = windows
    return Transport(
        scene=scene, photons=photons, seed=seed, window_radius=radius,
        windows=every_window.reshape(height, width, size, size, 3),
        path_length_images=truth.astype(np.float32), seconds=time.perf_counter() - started,
        measure=scene.measure, estimator=estimator, device=device.name,
    )


def _group_setup(scene: Scene, group: tuple[int, ...], volume: np.ndarray):
    """``(tables, majorant, optics)`` of a channel group for the materials used in ``volume``."""
    used = np.unique(volume)
    mus = np.array([m.mus[group[0]] for m in scene.materials])
    mua = np.array([[m.mua[channel] for m in scene.materials] for channel in group])
    tables, majorant = walk_tables(mus, mua, np.array([m.g for m in scene.materials]), used)
    mu_t = (mus + mua)[:, used]
    uniform = bool(np.all(mu_t == mu_t[:, :1]))
    return tables, majorant, optics(scene.n, scene.depth, scene.projector, scene.camera, 0.0 if uniform else -1.0)


def _store(windows, truth, rows, group, chunk_windows, chunk_truth, photons, add=False):
    """Put a channel group's raw chunk sums (per ``photons``) into the transport's arrays (the
    chunk's points at ``rows`` of ``windows``)."""
    for k, channel in enumerate(group):
        if add:
            windows[rows, :, :, channel] += chunk_windows[..., k] / photons
        else:
            windows[rows, :, :, channel] = chunk_windows[..., k] / photons
        truth[..., channel] += chunk_truth[..., k].sum(axis=0) / photons


def _analogue_work(scene, photons, seed, lit, streams, row_of, groups, windows, truth, device):
    """Steps (callables) of the analogue estimator: every lit point's photons on their own (point
    ``i`` walks on ``streams[i]`` and is summed into ``windows[row_of[i]]``)."""
    height, width = scene.height, scene.width
    camera = scene.measure == "camera"
    size = windows.shape[1]
    simulate_points = point_kernels(device)[0]
    per_call = POINTS_PER_CUDA_CALL if device.is_cuda else POINTS_PER_CALL

    def chunk_step(group, start):
        def step():
            tables, majorant, geometry = _group_setup(scene, group, scene.volume)
            columns = (column_optical_depths(scene.volume, tables[MU_T:MU_T + len(group)], scene.camera)
                       if camera and geometry[UNIFORM_MU_T] < 0 else np.zeros((0, 0, 0, 0)))
            chunk = lit[start:start + per_call]
            chunk_windows = np.zeros((len(chunk), size, size, len(group)))
            chunk_truth = np.zeros((min(TRUTH_BLOCKS, len(chunk)), scene.bin_count, height, width, len(group)))
            simulate_points(
                scene.volume, tables, majorant, geometry, columns, camera, chunk, photons, seed,
                streams[start:start + per_call] + group[0] * height * width,
                scene.bin_step, chunk_windows, chunk_truth,
            )
            _store(windows, truth, row_of[start:start + len(chunk)], group, chunk_windows, chunk_truth, photons)
        return step

    for group in groups:
        for start in range(0, len(lit), per_call):
            yield chunk_step(group, start)


def _reference_work(scene, photons, seed, lit, streams, row_of, groups, windows, truth, device):
    """Steps (callables) of the reference estimator (:mod:`.reference`): the allocation of the
    differences' photons (:mod:`.allocation`), then per channel group the reference kernel
    spread to every lit point and the correlated differences (``streams`` and ``row_of`` as
    :func:`_analogue_work` takes them)."""
    height, width = scene.height, scene.width
    camera = scene.measure == "camera"
    size = windows.shape[1]
    base = reference_volume(scene.volume)
    mixed = mixed_voxels(scene.volume, base, scene.n, scene.camera)
    # A walk can reach any column: every lit point needs its differences once one differs.
    differing = np.arange(len(lit)) if mixed.any() else np.zeros(0, np.int64)
    symmetric = scene.camera[0] == 0.0 and scene.projector[0] == 0.0
    base_geometry = reference_optics(scene.n, scene.depth, scene.projector, scene.camera, base)
    # Kernel streams sit above every point's walk streams.
    kernel_stream = CUDA_KERNEL_STREAM_BASE if device.is_cuda else 3 * height * width
    kernel_streams = CUDA_KERNEL_STREAMS if device.is_cuda else KERNEL_STREAMS
    per_call = POINTS_PER_CUDA_CALL if device.is_cuda else POINTS_PER_CALL
    kernel_photons = photons * len(lit) if len(differing) == 0 else max(1, int(photons * len(lit) * KERNEL_SHARE))
    # Photons per point of the differences, and the points scored whole (not kernel + difference).
    allocation = {"direct": np.zeros(len(lit), bool)}

    def pilot_step():
        allocation["photons"], allocation["direct"] = allocate(_reach_fractions(scene, lit.tobytes()), photons)

    def kernel_step(group):
        def step():
            # The majorant covers the scene's materials: the differences walk both volumes with it.
            tables, majorant, _ = _group_setup(scene, group, scene.volume)
            window, kernel = reference_kernel(
                base, tables, majorant, base_geometry, camera, scene.camera, kernel_photons, seed,
                kernel_stream + group[0] * kernel_streams, size // 2, (height, width), scene.bin_step,
                scene.bin_count, symmetric, device,
                # A GPU launches no thread without a photon.
                min(kernel_streams, kernel_photons) if device.is_cuda else kernel_streams)
            kept = ~allocation["direct"]
            for k, channel in enumerate(group):
                windows[row_of[kept], :, :, channel] += window[..., k]
                truth[..., channel] += spread_kernel(kernel[..., k:k + 1], lit[kept], (height, width))[..., 0]
        return step

    def difference_step(group, start):
        def step():
            tables, majorant, geometry = _group_setup(scene, group, scene.volume)
            chosen = differing[start:start + per_call]
            chunk = lit[chosen]
            chunk_windows = np.zeros((len(chunk), size, size, len(group)))
            chunk_truth = np.zeros((min(TRUTH_BLOCKS, len(chunk)), scene.bin_count, height, width, len(group)))
            simulate_point_differences(
                scene.volume, base, mixed, tables, majorant, geometry, base_geometry, camera, scene.camera, chunk,
                allocation["photons"][chosen], allocation["direct"][chosen], seed,
                streams[chosen] + group[0] * height * width, scene.bin_step, chunk_windows, chunk_truth, device)
            _store(windows, truth, row_of[chosen], group, chunk_windows, chunk_truth, 1, add=True)
        return step

    if len(differing):
        yield pilot_step
    for group in groups:
        yield kernel_step(group)
        for start in range(0, len(differing), per_call):
            yield difference_step(group, start)


@functools.lru_cache(maxsize=8)
def _reach_fractions(scene: Scene, lit_key: bytes) -> np.ndarray:
    """(n,) :func:`.allocation.reach_fractions` of the lit points (``lit_key``: their (n, 2)
    int64 ``[y, x]`` as bytes) by a pilot on the scene's own seed, cached per scene: every run of
    a scene (every batch of a progressive one) shares one allocation."""
    # A writable copy: the points' steps pass writable arrays, and a read-only one would compile
    # simulate_differences once more.
    lit = np.frombuffer(lit_key, np.int64).reshape(-1, 2).copy()
    height, width = scene.height, scene.width
    base = reference_volume(scene.volume)
    group = channel_groups(scene)[0]
    tables, majorant, geometry = _group_setup(scene, group, scene.volume)
    # Pilot streams sit above the points' walk streams and the kernel's.
    streams = 3 * height * width + 4 * KERNEL_STREAMS + lit[:, 0] * width + lit[:, 1]
    touches = simulate_point_differences(
        scene.volume, base, mixed_voxels(scene.volume, base, scene.n, scene.camera), tables, majorant, geometry,
        reference_optics(scene.n, scene.depth, scene.projector, scene.camera, base), scene.measure == "camera",
        scene.camera, lit, np.full(len(lit), PILOT_PHOTONS), np.zeros(len(lit), bool), scene.seed, streams,
        scene.bin_step, np.zeros((len(lit), 1, 1, len(group))),
        np.zeros((min(TRUTH_BLOCKS, len(lit)), 0, height, width, len(group))))  # scores discarded
    return reach_fractions(touches, lit, (height, width), PILOT_PHOTONS)


def slab_reflectance(material: Material, n: float) -> np.ndarray:
    """Diffuse reflectance (R, G, B) of a semi-infinite slab of ``material`` under index ``n``
    at normal incidence, per unit incident power, specular excluded: a layer's reference colour
    (docs/format/scene.md), exact by adding-doubling (:mod:`.adding_doubling`), not a Monte Carlo estimate."""
    return thick_slab_reflectance(material.mus, material.mua, material.g, n)


def write_transport(transport: Transport, out, *, overwrite: bool = False,
                    progress: Callable[[float], None] | None = None) -> Path:
    """Write a :class:`Transport` as an impulse dataset (docs/format/dataset.md), atomically."""
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
             f"not in the frames or path-length images\n"
             f"photons traced on {transport.device}")
    if transport.replicates:
        count = len(transport.replicates)
        notes += f"\n{count} independent replicates of {transport.photons // count} photons per point each (the frames' " \
                 "replicate key)"
    # With replicates, their frames are the dataset: a point's response is the mean of its frames.
    replicates = transport.replicates or (transport.windows,)
    labelled = len(replicates) > 1
    steps = len(frames) * len(replicates) + 1
    with DatasetWriter(out, (height, width), max_radius=scene.max_radius, pitch_mm=scene.pitch_mm,
                       notes=notes, sample=scene_sample(scene), overwrite=overwrite) as writer:
        for label, windows in enumerate(replicates):
            for index, lit in enumerate(frames):
                image = np.zeros((height, width, 3), np.float32)
                for qy, qx in lit:
                    py, px = qy + offsets[:, 0], qx + offsets[:, 1]
                    inside = (py >= 0) & (py < height) & (px >= 0) & (px < width)
                    image[py[inside], px[inside]] += windows[
                        qy, qx, offsets[inside, 0] + radius, offsets[inside, 1] + radius]
                writer.add_frame(image, lit, replicate=label if labelled else None)
                if progress is not None:
                    progress((label * len(frames) + index + 1) / steps)
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


def scene_sample(scene: Scene) -> Sample:
    """What a simulated dataset states of its surface (the manifest's ``sample`` key): the scene's
    index, and the anisotropy when every material shares one (else none is stated)."""
    anisotropies = {material.g for material in scene.materials}
    return Sample(n=float(scene.n), g=float(anisotropies.pop()) if len(anisotropies) == 1 else None)


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
