"""Bundled sample datasets (issue 12): compact storage that gives back the simulated transport,
datasets written from it whose stacks are the transport's, and the bundle's size and figures."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
from ringlight.app.main import main
from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.rings.geometry import ring_geometry
from ringlight.core.rings.stacks import ring_stack
from ringlight.core.simulate.convergence import ring_images
from ringlight.core.simulate.samples import SAMPLES, load_sample, sample_dataset, sample_names, save_sample
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import simulate_transport


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path / "cache"))


def test_every_sample_is_bundled_at_48_or_more_within_25_mb():
    assert sample_names() == list(SAMPLES)
    folder = resources.files("ringlight.resources.samples")
    sizes = [len(folder.joinpath(f"{name}.npz").read_bytes()) for name in SAMPLES]
    assert sum(sizes) < 25e6, sizes
    for name in SAMPLES:
        transport, noise = load_sample(name)
        assert transport.scene.height >= 48 and transport.scene.width >= 48
        assert transport.scene.max_radius >= 10 and len(noise) >= 11
        assert np.all(np.isfinite(transport.windows))


@pytest.mark.parametrize("name", ["layers3", "skin1"])
def test_layered_samples_are_clean_to_max_radius(name):
    # Shift invariance: one simulation serves every lit point (the stored figure of make_samples).
    _, noise = load_sample(name)
    assert np.all(noise[:11] <= 0.05), noise


def test_a_sample_file_gives_back_its_transport(tmp_path, monkeypatch):
    scene = parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": 9, "width": 9}, "depth": 10, "n": 1.3,
        "materials": {"m": {"mus": [1.0] * 3, "mua": [0.05, 0.1, 0.2]}, "b": {"mus": [0.4] * 3, "mua": [0.3] * 3}},
        "background": "m", "shapes": [{"type": "sphere", "material": "b", "center": [4, 4, 2], "radius": 2}],
        "max_radius": 3,
    }, name="tiny")
    transport = simulate_transport(scene, photons=40, seed=1)
    path = tmp_path / "tiny.npz"
    save_sample(transport, path, np.arange(3.0))
    monkeypatch.setattr("ringlight.core.simulate.samples.sample_names", lambda: ["tiny"])
    monkeypatch.setattr("ringlight.core.simulate.samples.load_scene", lambda name, size: scene)
    monkeypatch.setattr("ringlight.core.simulate.samples.resources.files", lambda package: tmp_path)
    back, noise = load_sample("tiny")
    # Inside the disc of max_radius: float16 ratios to the largest value of each offset.
    radius = transport.window_radius
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    disc = yy ** 2 + xx ** 2 <= scene.max_radius ** 2
    scale = np.abs(transport.windows[:, :, disc]).max(axis=(0, 1))
    np.testing.assert_allclose(back.windows[:, :, disc], transport.windows[:, :, disc], rtol=0, atol=float(scale.max()) * 1e-3)
    assert np.all(back.windows[:, :, ~disc] == 0)
    np.testing.assert_array_equal(back.path_length_images, transport.path_length_images)
    np.testing.assert_array_equal(noise, np.arange(3.0))
    # Written as a dataset, its ring light stack is the transport's own (brute force from the windows).
    dataset = open_dataset(sample_dataset("tiny"))
    stack = ring_stack(dataset, [0.0, 1.0, 2.0])
    expected = ring_images(back.windows.astype(np.float64), [0.0, 1.0, 2.0])
    np.testing.assert_allclose(stack.images, expected, rtol=1e-5, atol=1e-7)


def test_the_demo_command_writes_a_sample_once_and_describes_it(capsys):
    # star, not the default (test_cli covers that): a fifth of layers3's 5000 frames to write.
    assert main(["demo", "--sample", "star"]) == 0
    first = capsys.readouterr().out
    assert "48" in first
    folder = next(iter(sample_dataset("star").parent.glob("star-*")))
    stamp = (folder / "dataset.json").stat().st_mtime_ns
    assert main(["demo", "--sample", "star"]) == 0
    assert (folder / "dataset.json").stat().st_mtime_ns == stamp  # not written again


def test_ring_images_of_a_grid_smaller_than_its_rings_equal_brute_force():
    """A 4 x 3 grid whose windows reach 6 steps: rings wider than the grid have members off it on
    every side (simulate --noise on a 4 x 4 grid failed to broadcast: a slice's stop went negative).
    Brute force: each point's mean over the ring members q = p + d on the grid, seen at offset -d."""
    rng = np.random.default_rng(3)
    height, width, radius = 4, 3, 6
    windows = rng.uniform(0.0, 1.0, (height, width, 2 * radius + 1, 2 * radius + 1, 3))
    radii = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    images = ring_images(windows, radii)
    for index, r in enumerate(radii):
        for y in range(height):
            for x in range(width):
                members = [windows[y + dy, x + dx, radius - dy, radius - dx]
                           for dy, dx in ring_geometry(r).offsets
                           if 0 <= y + dy < height and 0 <= x + dx < width]
                expected = np.mean(members, axis=0) if members else np.full(3, np.nan)
                np.testing.assert_allclose(images[index, y, x], expected, rtol=1e-12)
