"""Bundled sample datasets (napari's File > Open Sample): simulated once by ``tools/make_samples.py``,
shipped compactly in ``ringlight.resources.samples`` and written out as impulse datasets (docs/format) into
the user cache on first use (a second or two, no simulation).

A sample file (``NAME.npz``) holds a :class:`.transport.Transport` in little space: the windows
inside the disc of ``max_radius`` only (the frames hold nothing else), as float16 ratios to a
float32 scale per offset and channel (relative precision 5e-4, far below the noise), or, for a
layered scene where every lit point sees the same response, that one response (and, when the
sample was simulated in independent replicates, :mod:`ringlight.core.simulate.replicates`, each replicate's response:
the dataset then holds them as its replicates, and its noise is measured); the path-length images
in float32; the scene is the preset at the stored size. Its ``noise`` array is the estimated
relative noise of T_r per radius that ``make_samples`` printed.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np

from ..dataset.cache import user_cache_root
from ..dataset.disc import disc_offsets
from ..dataset.copy import copy_dataset
from ..dataset.writer import is_dataset_folder
from ..errors import RinglightError
from .presets import load_scene
from .transport import Transport, write_transport

SAMPLES = ("red-bead", "star", "layers3", "skin1")
"""The bundled samples, in menu order."""
DEMO_SAMPLE = "red-bead"
"""The sample ``ringlight`` opens with no dataset (the demo dataset)."""
SAMPLE_VERSION = 1
WRITTEN_VERSION = 2
"""What a sample's dataset holds beyond its bundled file: 2 adds the manifest's ``sample`` key (the
scene's n and g). Part of the sample folder's name, so a sample written before is written anew."""


class SampleError(RinglightError):
    """A sample that is not bundled or cannot be read."""


def sample_names() -> list[str]:
    """The samples bundled with this installation, in :data:`SAMPLES` order."""
    folder = resources.files("ringlight.resources.samples")
    present = {item.name[:-4] for item in folder.iterdir() if item.name.endswith(".npz")}
    return [name for name in SAMPLES if name in present]


def save_sample(transport: Transport, path: Path, noise: np.ndarray) -> None:
    """Write ``transport`` compactly to ``path`` (see the module notes); ``noise`` (radii,)."""
    scene = transport.scene
    offsets = disc_offsets(scene.max_radius) + transport.window_radius
    inside = transport.windows[:, :, offsets[:, 0], offsets[:, 1], :].astype(np.float32)  # (H, W, k, 3)
    shared = bool(np.all(inside == inside[:1, :1]))
    fields = dict(version=SAMPLE_VERSION, name=scene.name, size=[scene.height, scene.width],
                  photons=transport.photons, seed=transport.seed, seconds=transport.seconds,
                  estimator=transport.estimator, measure=transport.measure, shared=shared)
    arrays = {"truth": transport.path_length_images.astype(np.float32), "noise": np.asarray(noise, np.float32)}
    if transport.replicates:
        replicates = [windows[:, :, offsets[:, 0], offsets[:, 1], :].astype(np.float32)
                      for windows in transport.replicates]
        if not shared or not all(np.all(each == each[:1, :1]) for each in replicates):
            raise SampleError(f"{path}: a sample keeps replicates only of a response every lit point shares")
        arrays["replicates"] = np.stack([each[0, 0] for each in replicates])
    if shared:
        arrays["response"] = inside[0, 0]
    else:
        scale = np.abs(inside).max(axis=(0, 1))
        scale[scale == 0] = 1.0
        arrays["scale"] = scale.astype(np.float32)
        arrays["ratio"] = (inside / scale).astype(np.float16)
    with open(path, "wb") as handle:
        np.savez_compressed(handle, fields=json.dumps(fields), **arrays)


def load_sample(name: str) -> tuple[Transport, np.ndarray]:
    """The bundled sample ``name`` as a transport, and its noise per radius."""
    if name not in sample_names():
        raise SampleError(f"{name}: no such sample (bundled: {', '.join(sample_names()) or 'none'})")
    resource = resources.files("ringlight.resources.samples").joinpath(f"{name}.npz")
    with resources.as_file(resource) as path, np.load(path, allow_pickle=False) as data:
        fields = json.loads(str(data["fields"]))
        scene = replace(load_scene(fields["name"], size=tuple(fields["size"])), measure=fields["measure"])
        radius = math.ceil(scene.max_radius)
        offsets = disc_offsets(scene.max_radius) + radius
        if fields["shared"]:
            inside = np.broadcast_to(data["response"], (scene.height, scene.width) + data["response"].shape)
        else:
            inside = data["ratio"].astype(np.float32) * data["scale"]
        def windows_of(responses):
            windows = np.zeros((scene.height, scene.width, 2 * radius + 1, 2 * radius + 1, 3), np.float32)
            windows[:, :, offsets[:, 0], offsets[:, 1], :] = responses
            return windows

        replicates = tuple(windows_of(response) for response in data["replicates"]) if "replicates" in data else ()
        transport = Transport(scene=scene, photons=fields["photons"], seed=fields["seed"], window_radius=radius,
                              windows=windows_of(inside), path_length_images=data["truth"], seconds=fields["seconds"],
                              measure=fields["measure"], estimator=fields["estimator"], replicates=replicates)
        return transport, data["noise"].copy()


def sample_folder(name: str) -> Path:
    """Where sample ``name`` is (or will be) written as a dataset in the user cache; the name
    carries a hash of the bundled file and :data:`WRITTEN_VERSION`, so a newer sample (or one
    written to a newer rule) is written anew."""
    if name not in sample_names():
        raise SampleError(f"{name}: no such sample (bundled: {', '.join(sample_names()) or 'none'})")
    resource = resources.files("ringlight.resources.samples").joinpath(f"{name}.npz")
    digest = hashlib.sha256(resource.read_bytes() + f"written {WRITTEN_VERSION}".encode()).hexdigest()[:12]
    return user_cache_root() / "samples" / f"{name}-{digest}"


def sample_dataset(name: str, progress=None) -> Path:
    """The folder of sample ``name`` as a dataset (:func:`sample_folder`), written on first use."""
    path = sample_folder(name)
    if not is_dataset_folder(path):
        transport, _ = load_sample(name)
        write_transport(transport, path, overwrite=True, progress=progress)
    return path


def write_sample(name: str, out, *, overwrite: bool = False, progress=None) -> Path:
    """Sample ``name`` as a dataset in the folder ``out`` (a new folder, or with ``overwrite`` an
    earlier dataset holding nothing else); returns ``out`` as a Path. A copy of the user cache's
    (:func:`sample_folder`) when it holds the sample: the same files, as its folder's name carries
    the bundled file's hash and the writing rule (5000 frames copied in about a second, where
    writing them anew takes about 10 CPU-s); else written from the bundled file."""
    cached = sample_folder(name)
    if is_dataset_folder(cached):
        return copy_dataset(cached, out, overwrite=overwrite, progress=progress)
    transport, _ = load_sample(name)
    return write_transport(transport, out, overwrite=overwrite, progress=progress)


def ensure_demo_dataset(progress=None) -> Path:
    """The demo dataset: the :data:`DEMO_SAMPLE` sample as a dataset (:func:`sample_dataset`)."""
    return sample_dataset(DEMO_SAMPLE, progress)
