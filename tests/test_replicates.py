"""Independent replicates of a capture (FORMAT.md's frame key ``replicate``): the manifest's checks,
the standard errors of ring light and transient images and of a region's profile from the
replicates' spread (against brute force by the definitions), the simulator's replicates, and
their standard errors against the spread of independently simulated datasets."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from ringlight.core.dataset.impulse_dataset import open_dataset
from ringlight.core.dataset.manifest import read_manifest
from ringlight.core.errors import DatasetError
from ringlight.core.inversion.measured import measured_profile
from ringlight.core.rings.geometry import ring_geometry
from ringlight.core.rings.noise import stack_noise
from ringlight.core.simulate.convergence import ring_images
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.replicates import simulate_replicates
from ringlight.core.simulate.samples import sample_dataset
from ringlight.core.simulate.transport import simulate_transport, write_transport

from reference import brute_ring_image, random_impulses, write_rgb

HEIGHT = WIDTH = 7
COUNT = 4


def write_replicates(folder, replicates):
    """A dataset of one frame per lit point and replicate: ``replicates`` is a list of impulse
    dictionaries {(y, x): (H, W, 3)} lighting the same points."""
    (folder / "frames").mkdir(parents=True)
    frames = []
    for label, impulses in enumerate(replicates):
        for (y, x), image in sorted(impulses.items()):
            name = f"frames/{label}_{y}_{x}.exr"
            write_rgb(folder / name, image)
            frames.append({"file": name, "lit": [[y, x]], "replicate": label})
    manifest = {"format": "ringlight-impulse", "version": 1, "grid": {"height": HEIGHT, "width": WIDTH},
                "max_radius": 4.5, "frames": frames}
    (folder / "dataset.json").write_text(json.dumps(manifest))
    return manifest


@pytest.fixture(scope="module")
def replicated(tmp_path_factory):
    """Four replicates of random impulses: a common response plus noise of each replicate's own,
    shared by every lit point (as a simulator's kernel) and per point."""
    rng = np.random.default_rng(5)
    common = random_impulses(rng, HEIGHT, WIDTH, 4)
    replicates = []
    for _ in range(COUNT):
        shared = rng.normal(1.0, 0.1, 3).astype(np.float32)
        replicates.append({q: (image * shared * rng.normal(1.0, 0.05, image.shape)).astype(np.float32)
                           for q, image in common.items()})
    folder = tmp_path_factory.mktemp("replicated") / "d"
    write_replicates(folder, replicates)
    return folder, replicates


def test_a_manifests_replicates_are_read_and_kept_by_a_reopen(replicated):
    folder, _ = replicated
    assert read_manifest(folder).replicates == tuple(range(COUNT))
    first = open_dataset(folder)
    again = open_dataset(folder)  # the store's manifest copy
    assert [f.replicate for f in again.manifest.frames] == [f.replicate for f in first.manifest.frames]
    assert again.manifest.replicates == tuple(range(COUNT))


def test_replicates_that_light_different_points_or_bad_labels_are_one_line(tmp_path):
    rng = np.random.default_rng(1)
    impulses = random_impulses(rng, HEIGHT, WIDTH, 4)
    fewer = dict(list(impulses.items())[:-1])
    folder = tmp_path / "a"
    write_replicates(folder, [impulses, fewer])
    with pytest.raises(DatasetError, match=r"replicate 1 lights 48 points and replicate 0 49: every replicate must "
                                           r"light the same points"):
        read_manifest(folder)
    for label in (-1, 1.5, "0", True):
        manifest = json.loads((folder / "dataset.json").read_text())
        manifest["frames"][0]["replicate"] = label
        (folder / "dataset.json").write_text(json.dumps(manifest))
        with pytest.raises(DatasetError, match=r"'frames\[0\]\.replicate' must be a whole number in \[0, "):
            read_manifest(folder)


def test_standard_errors_of_ring_and_transient_images_are_the_replicates_spread(replicated):
    """Brute force: each replicate's E_r by the definition (every pixel, every lit point), T_r =
    E_r - E_{r+1}, their standard deviation over the replicates (ddof 1) over sqrt(K)."""
    folder, replicates = replicated
    noise = stack_noise(open_dataset(folder), [1.0, 2.0])
    for row, radius in enumerate((1.0, 2.0)):
        rings = np.stack([brute_ring_image(impulses, HEIGHT, WIDTH, radius) for impulses in replicates])
        outer = np.stack([brute_ring_image(impulses, HEIGHT, WIDTH, radius + 1) for impulses in replicates])
        np.testing.assert_allclose(noise.ring[row], rings.std(axis=0, ddof=1) / math.sqrt(COUNT), rtol=1e-4)
        np.testing.assert_allclose(noise.transient[row], (rings - outer).std(axis=0, ddof=1) / math.sqrt(COUNT),
                                   rtol=1e-4, atol=1e-7)
        luminance = (rings - outer) @ noise.luminance_weights
        np.testing.assert_allclose(noise.transient_luminance[row], luminance.std(axis=0, ddof=1) / math.sqrt(COUNT),
                                   rtol=1e-4, atol=1e-7)


def brute_region_profile(impulses, radii):
    """(R, 3) the mean over lit points q of q's own ring mean of I_q(q + d), members in the grid."""
    out = []
    for radius in radii:
        ring = ring_geometry(radius, 1.0, False)
        profiles = []
        for (qy, qx), image in impulses.items():
            values = [image[qy + dy, qx + dx] for dy, dx in ring.offsets
                      if 0 <= qy + dy < HEIGHT and 0 <= qx + dx < WIDTH]
            profiles.append(np.mean(values, axis=0))
        out.append(np.mean(profiles, axis=0))
    return np.array(out)


def test_a_regions_profile_has_the_replicates_spread_and_covariance_and_no_floor(replicated):
    folder, replicates = replicated
    radii = np.arange(0.0, 4.0)
    measured = measured_profile(open_dataset(folder), np.ones((HEIGHT, WIDTH), bool), radii)
    per_replicate = np.stack([brute_region_profile(impulses, radii) for impulses in replicates])  # (K, R, 3)
    np.testing.assert_allclose(measured.mean, per_replicate.mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(measured.standard_error, per_replicate.std(axis=0, ddof=1) / math.sqrt(COUNT),
                               rtol=1e-4)
    for row in range(len(radii)):
        np.testing.assert_allclose(measured.covariance[row], np.cov(per_replicate[:, row].T) / COUNT, rtol=1e-4)
    assert measured.replicates == COUNT and measured.floor == 0.0


def test_the_simulators_replicates_are_independent_runs_whose_mean_is_the_dataset(tmp_path):
    scene = load_scene("layers3", size=(6, 6))
    transport = simulate_replicates(scene, 32, 4, seed=3)
    assert transport.photons == 32 and len(transport.replicates) == 4
    np.testing.assert_allclose(transport.windows, np.mean(transport.replicates, axis=0), rtol=1e-6, atol=1e-9)
    single = simulate_transport(scene, 8, seed=3)  # replicate 0 keeps the run's seed
    np.testing.assert_array_equal(transport.replicates[0], single.windows)
    assert not np.array_equal(transport.replicates[1], transport.replicates[0])
    write_transport(transport, tmp_path / "d")
    manifest = read_manifest(tmp_path / "d")
    assert manifest.replicates == (0, 1, 2, 3) and manifest.sample.n == scene.n
    # The dataset's responses, each the mean of its point's four frames, are those of the mean
    # windows written as one dataset.
    write_transport(replace(transport, replicates=()), tmp_path / "mean")
    assert read_manifest(tmp_path / "mean").replicates == (0,)
    np.testing.assert_allclose(open_dataset(tmp_path / "d").responses, open_dataset(tmp_path / "mean").responses,
                               rtol=2e-6, atol=1e-9)


def test_replicate_standard_errors_match_the_spread_of_independent_simulations():
    """A layered scene's noise is shared by every lit point (one kernel), so the members' spread
    shows almost none of it. The replicates' standard error of E_r (8 replicates of 8 photons)
    must match the spread of E_r over 8 independent simulations of 64 photons: their variances
    pooled over pixels, radii 1..5 and channels agree within a factor 2 (each pooled estimate has
    tens of degrees of freedom)."""
    scene = load_scene("layers3", size=(8, 8))
    radii = np.arange(1.0, 6.0)
    transport = simulate_replicates(scene, 64, 8, seed=21)
    replicate_rings = np.stack([ring_images(w.astype(np.float64), radii) for w in transport.replicates])
    replicate_variance = replicate_rings.var(axis=0, ddof=1) / len(replicate_rings)
    independent = np.stack([ring_images(simulate_transport(scene, 64, seed=100 + s).windows.astype(np.float64), radii)
                            for s in range(8)])
    spread = independent.var(axis=0, ddof=1)
    ratio = np.nanmean(replicate_variance / spread.clip(1e-300))
    assert 0.5 < ratio < 2.0


def test_the_bundled_layered_samples_have_nonzero_standard_errors_at_every_radius(link_sample):
    """layers3 ships its replicates (as skin1 does): every standard error of E_r and T_r is finite
    and above 0, r = 0 included (the members' spread gave 0 at r = 0 and 0.005-0.03 % elsewhere,
    the replicates 0.1-3 %)."""
    for name in ("layers3",):
        link_sample(name)  # as sample_dataset writes it, written once for the whole run
        dataset = open_dataset(sample_dataset(name))
        assert len(dataset.manifest.replicates) == 8
        noise = stack_noise(dataset, np.arange(0.0, 6.0))
        assert np.all(np.isfinite(noise.ring)) and np.all(noise.ring > 0) and np.all(noise.transient > 0)
        centre = dataset.grid_shape[0] // 2
        relative = noise.ring[:, centre, centre] / np.abs(dataset.point(centre, centre)[0])
        assert np.all(relative[0] > 1e-4)
