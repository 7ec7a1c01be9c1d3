"""The camera measure (FORMAT.md "What a simulated frame holds") against exact and independent values.

- Chandrasekhar's law of diffuse reflection for an isotropic half-space (n = 1): the reflectance
  factor toward any camera, for any beam, is albedo H(mu) H(mu0) / (4 (mu + mu0)).
- Integrated over all camera directions, (value / pi) cos th_o dw_o is the exitance.
- The radial ratio pi x camera radiance / exitance of issue 18's table (an independent renderer and
  an independent Monte Carlo agreed on it).
- The voxel traversal's optical depth against a brute-force sum along the ray.
"""

import json
import math
from importlib import resources

import numba
import numpy as np
import pytest
from reference import assert_same_for_any_thread_count
from ringlight.core import read_manifest
from ringlight.core.simulate.camera import (
    VIEW_Y,
    VIEW_Z,
    column_optical_depths,
    optical_depth_to_surface,
    optics,
)
from ringlight.core.simulate.photon import simulate_points, total_run
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.tables import single_channel_tables, walk_tables
from ringlight.core.simulate.transport import (
    simulate_transport,
    simulated_measure,
    write_transport,
)

ONE_VOXEL = np.zeros((1, 1, 1), np.uint8)


def chandrasekhar_h(albedo: float, mu: np.ndarray, nodes: int = 64) -> np.ndarray:
    """Chandrasekhar's H-function for isotropic scattering, from its nonlinear integral equation
    1 / H(mu) = sqrt(1 - albedo) + albedo / 2 int_0^1 mu' H(mu') / (mu + mu') dmu' (Gauss-Legendre)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = (x + 1) / 2, w / 2
    h = np.ones(nodes)
    for _ in range(300):
        h = 1 / (math.sqrt(1 - albedo) + albedo / 2 * (w * x * h / (x[:, None] + x)).sum(axis=1))
    mu = np.atleast_1d(np.asarray(mu, float))
    return 1 / (math.sqrt(1 - albedo) + albedo / 2 * (w * x * h / (mu[:, None] + x)).sum(axis=1))


def total(mu_t, albedo, g, geometry, camera, photons, seed):
    """Mean total score per photon over the whole surface and its standard error."""
    (sums,), (squares,) = total_run(ONE_VOXEL, *single_channel_tables([mu_t], [albedo], [g]), geometry, camera,
                                    photons, seed, 0)
    mean = sums / photons
    return mean, math.sqrt(max(squares / photons - mean * mean, 0.0) / photons)


def test_the_h_function_gives_the_published_half_space_reflectance():
    # 1 - H(1) sqrt(1 - albedo) is the total reflectance: 0.41495 for albedo 0.9 (adding-doubling).
    assert 1 - chandrasekhar_h(0.9, 1.0)[0] * math.sqrt(0.1) == pytest.approx(0.41495, abs=2e-5)


@pytest.mark.parametrize("projector, camera", [
    ((0, 0), (0, 0)), ((0, 0), (60, 0)), ((60, 30), (0, 0)), ((45, 0), (45, 180)), ((30, 90), (75, 10)),
])
def test_isotropic_half_space_follows_chandrasekhars_law_of_diffuse_reflection(projector, camera):
    # Chandrasekhar (1960), Radiative Transfer, Sec. 47: I(mu, mu0) = F albedo / 4 x mu0 / (mu + mu0)
    # x H(mu) H(mu0) under a beam of flux pi F across it; with unit power on the surface,
    # pi F mu0 = 1, the reflectance factor pi I is albedo H(mu) H(mu0) / (4 (mu + mu0)), whatever
    # the azimuths. Summed over the surface, the frame of one lit pixel is that.
    albedo = 0.9
    mu, mu0 = math.cos(math.radians(camera[0])), math.cos(math.radians(projector[0]))
    expected = albedo * chandrasekhar_h(albedo, mu)[0] * chandrasekhar_h(albedo, mu0)[0] / (4 * (mu + mu0))
    value, error = total(1.0, albedo, 0.0, optics(1.0, np.inf, projector, camera, 1.0), True, 40_000, 11)
    assert abs(value - expected) < 3 * error, (value, error, expected)
    assert error < 0.01 * expected


def test_camera_measure_integrated_over_camera_directions_is_the_exitance():
    # int (value / pi) cos th_o dw_o over the upper hemisphere = the exitance (the module notes of
    # ringlight.core.simulate.camera): Gauss-Legendre in cos th_o, uniform in azimuth. A refractive,
    # forward-scattering, finite slab under an oblique beam, so that every factor and the azimuth
    # matter. The same seeds drive every camera direction (the walk does not depend on it), so
    # the batches' spread is the error of the whole quadrature.
    n, depth, projector = 1.4, 4.0, (40.0, 30.0)
    mu_t, albedo, g = 1.0, 0.95, 0.5
    nodes, weights = np.polynomial.legendre.leggauss(8)
    cosines, weights = (nodes + 1) / 2, weights / 2
    azimuths = np.arange(6) * 60.0
    differences = []
    for batch in range(4):
        integral = 0.0
        for cosine, weight in zip(cosines, weights):
            for azimuth in azimuths:
                camera = (math.degrees(math.acos(cosine)), azimuth)
                value, _ = total(mu_t, albedo, g, optics(n, depth, projector, camera, mu_t), True, 4000, batch)
                integral += value / math.pi * cosine * weight * 2 * math.pi / len(azimuths)
        exitance, _ = total(mu_t, albedo, g, optics(n, depth, projector, (0, 0), mu_t), False, 4000, batch)
        differences.append((integral, exitance))
    integral, exitance = np.array(differences).T
    gap = integral - exitance
    error = gap.std(ddof=1) / math.sqrt(len(gap))
    assert abs(gap.mean()) < 3 * error, (integral, exitance)
    assert error < 0.01 * exitance.mean()


def slab_scene(n, measure, radius=4, camera=(0.0, 0.0)):
    """Issue 18's slab: mus 6, mua 0.5 per mm, g 0, pitch 0.1 mm, 2 mm deep."""
    size = 2 * radius + 1
    return parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": size, "width": size, "pitch_mm": 0.1},
        "depth": 20, "n": n, "materials": {"slab": {"mus": [6, 6, 6], "mua": [0.5, 0.5, 0.5], "g": 0}},
        "background": "slab", "max_radius": radius, "measure": measure, "camera": {"direction": list(camera)},
    })


def radial_profile(window):
    """Means over the pixels at |d| in [r - 0.5, r + 0.5), r = 0..4, of a (9, 9) window."""
    yy, xx = np.mgrid[-4:5, -4:5]
    distance = np.hypot(yy, xx)
    return np.array([window[(distance >= r - 0.5) & (distance < r + 0.5)].mean() for r in range(5)])


@pytest.mark.parametrize("n, table", [
    (1.0, [1.64, 0.63, 0.75, 0.81, 0.85]),
    (1.4, [1.48, 0.75, 0.95, 0.98, 1.00]),
])
def test_camera_over_exitance_per_radius_matches_the_independent_renderer(n, table):
    # Issue 18: pi x camera radiance / exitance, r = 0..4, from an independent renderer and an
    # independent Monte Carlo, given to 2 decimals (so +-0.005 on top of 3 standard errors).
    # Same seed, same walks: each batch's ratio pairs the two measures of the same photons.
    ratios = []
    for seed in range(6):
        camera, exitance = (radial_profile(simulate_transport(slab_scene(n, measure), photons=40_000, seed=seed,
                                                              points=[[4, 4]]).windows[4, 4, :, :, 0])
                            for measure in ("camera", "exitance"))
        ratios.append(camera / exitance)
    ratios = np.array(ratios)
    mean, error = ratios.mean(axis=0), ratios.std(axis=0, ddof=1) / math.sqrt(len(ratios))
    assert np.all(np.abs(mean - table) < 3 * error + 0.005), (mean, error)


def brute_optical_depth(volume, mu_t, z, y, x, direction, steps=200_000):
    """Midpoint sum of mu_t along the segment to the surface, voxel looked up at each sample."""
    length = z / -direction[2]
    t = (np.arange(steps) + 0.5) / steps * length
    pz, py, px = z + t * direction[2], y + t * direction[0], x + t * direction[1]
    layers, height, width = volume.shape
    material = volume[np.minimum(pz.astype(int), layers - 1),
                      np.clip(np.floor(py + 0.5).astype(int), 0, height - 1),
                      np.clip(np.floor(px + 0.5).astype(int), 0, width - 1)]
    return mu_t[material].sum() * length / steps


def test_voxel_traversal_gives_the_optical_depth_along_oblique_paths():
    rng = np.random.default_rng(4)
    volume = rng.integers(0, 3, (6, 5, 7)).astype(np.uint8)
    mu_t = np.array([0.2, 1.0, 3.0])
    for _ in range(20):
        zenith, azimuth = rng.uniform(0, 60), rng.uniform(0, 360)
        view = optics(1.3, 6.0, camera=(zenith, azimuth))[VIEW_Y:VIEW_Z + 1]
        z, y, x = rng.uniform(0.1, 5.9), rng.uniform(-2, 6), rng.uniform(-2, 8)
        exact = np.zeros(2)
        optical_depth_to_surface(volume, np.stack([mu_t, 2 * mu_t[::-1]]), z, y, x, *view, 1e9, exact)
        reference = [brute_optical_depth(volume, table, z, y, x, view) for table in (mu_t, 2 * mu_t[::-1])]
        np.testing.assert_allclose(exact, reference, rtol=1e-3)


def test_layered_oblique_camera_simulation_is_deterministic_whatever_the_thread_count():
    document = json.loads(resources.files("ringlight.resources.scenes").joinpath("layers3.json").read_text())
    document.update(camera={"direction": [35, 20]}, projector={"direction": [20, 200]})
    scene = parse_scene(document, size=(8, 8))
    first = assert_same_for_any_thread_count(lambda: simulate_transport(scene, photons=40))
    assert first.windows.sum() > 0


def test_datasets_say_which_measure_they_hold(tmp_path):
    transport = simulate_transport(slab_scene(1.0, "exitance", radius=1), photons=20)
    write_transport(transport, tmp_path / "ds")
    manifest_path = tmp_path / "ds" / "dataset.json"
    assert simulated_measure(read_manifest(tmp_path / "ds")) == "exitance"
    document = json.loads(manifest_path.read_text())
    # Before the camera measure the notes were one line without a measure: legacy exitance.
    document["notes"] = document["notes"].split("\n")[0]
    manifest_path.write_text(json.dumps(document))
    assert simulated_measure(read_manifest(tmp_path / "ds")) == "exitance"
    # Not simulated by ringlight (no ground truth): no claim.
    del document["ground_truth"]
    manifest_path.write_text(json.dumps(document))
    assert simulated_measure(read_manifest(tmp_path / "ds")) is None


def test_a_column_table_is_the_sum_above_each_voxel_in_one_layout_for_any_channel_count():
    """Brute force: mu_t summed over the voxels above. In C order for one channel or three, however
    wide the volume: numba compiles the walk, and each kernel that calls it, once per layout, and
    the fancy index gave three channels numba's 'A' layout ('F' one pixel wide)."""
    rng = np.random.default_rng(4)
    for shape in ((6, 4, 5), (6, 1, 1)):
        volume = rng.integers(0, 3, shape).astype(np.uint8)
        for mu_t in (np.array([0.5, 2.0, 0.25]), np.array([[0.5, 2.0, 0.25], [0.1, 1.0, 3.0], [0.3, 0.7, 0.0]])):
            columns = column_optical_depths(volume, mu_t)
            assert numba.typeof(columns).layout == "C", (shape, mu_t.shape, columns.strides)
            per_channel = np.atleast_2d(mu_t)
            brute = np.array([[[[sum(per_channel[c, volume[k, y, x]] for k in range(z)) for x in range(shape[2])]
                                for y in range(shape[1])] for z in range(shape[0])] for c in range(len(per_channel))])
            np.testing.assert_allclose(columns, brute, rtol=1e-12, atol=0.0)


def test_the_column_table_of_a_straight_down_camera_gives_the_traversals_result():
    # Both are exact, so the same walks give the same frames up to rounding.
    scene = load_scene("red-bead", size=(6, 6))
    mus = np.array([m.mus[0] for m in scene.materials])
    mua = np.array([[m.mua[c] for m in scene.materials] for c in range(3)])
    tables, majorant = walk_tables(mus, mua, np.array([m.g for m in scene.materials]))
    lit = np.array([[2, 3], [4, 1]])
    frames = []
    for columns in (column_optical_depths(scene.volume, mus + mua), np.zeros((0, 0, 0, 0))):
        windows, truth = np.zeros((2, 9, 9, 3)), np.zeros((2, 8, 6, 6, 3))
        simulate_points(scene.volume, tables, majorant, optics(1.4, scene.depth), columns, True,
                        lit, 300, 3, np.array([0, 1]), 1.0, windows, truth)
        frames.append(windows)
    assert frames[0].sum() > 0
    np.testing.assert_allclose(frames[0], frames[1], rtol=1e-9, atol=1e-15)
