"""Monte Carlo simulator against published values, analytic diffusion, and its own bookkeeping."""

import math

import numpy as np
import pytest
from reference import assert_same_for_any_thread_count
from ringlight.app.main import main
from ringlight.core import Cancelled, open_dataset, read_manifest, ring_stack
from ringlight.core.simulate.camera import optics, specular_reflectance
from ringlight.core.simulate.lattice import lattice_frames
from ringlight.core.simulate.photon import reflectance_run, trace_events
from ringlight.core.simulate.presets import load_scene, preset_names, preset_notes
from ringlight.core.simulate.scene import SceneError, parse_scene
from ringlight.core.simulate.tables import single_channel_tables, walk_tables
from ringlight.core.simulate.transport import (
    simulate_transport,
    simulated_measure,
    write_transport,
)

ONE_VOXEL = np.zeros((1, 1, 1), np.uint8)


def reflectance(mua, mus, g, n, depth, photons, stream=0):
    """Total diffuse reflectance (specular excluded, entry loss included) and its standard error."""
    mu_t = mua + mus
    (total,), (total_sq,) = reflectance_run(ONE_VOXEL, *single_channel_tables([mu_t], [mus / mu_t], [g]), n, depth,
                                            photons, 7, stream)
    mean = total / photons
    error = math.sqrt(max(total_sq / photons - mean * mean, 0.0) / photons)
    keep = 1.0 - specular_reflectance(n)
    return mean * keep, error * keep


def test_mcml_slab_diffuse_reflectance_matches_van_de_hulst():
    # MCML manual Table 6.1: n = 1, mu_a = 10/cm, mu_s = 90/cm, g = 0.75, d = 0.02 cm (lengths in cm).
    # van de Hulst (1980): R_d = 0.09739; MCML: 0.09734 +- 0.00035.
    rd, se = reflectance(10.0, 90.0, 0.75, 1.0, 0.02, 200_000)
    assert abs(rd - 0.09739) < 3 * se, (rd, se)


def test_half_space_total_reflectance_matches_giovanelli():
    # n = 1.5, mu_a = 10, mu_s = 90, g = 0, semi-infinite: total reflectance 0.2600 including the
    # 0.04 specular reflection (Giovanelli 1955; MCML's diffuse part is about 0.220).
    rd, se = reflectance(10.0, 90.0, 0.0, 1.5, np.inf, 150_000)
    total = rd + specular_reflectance(1.5)
    assert specular_reflectance(1.5) == pytest.approx(0.04)
    assert abs(total - 0.2600) < 3 * se, (total, se)


def test_matched_isotropic_half_space_matches_adding_doubling():
    # Albedo 0.9, g = 0, n = 1, semi-infinite: R = 0.41495 (adding-doubling).
    rd, se = reflectance(0.1, 0.9, 0.0, 1.0, np.inf, 150_000)
    assert abs(rd - 0.41495) < 3 * se, (rd, se)


def farrell_dipole(rho, mua, mus_reduced, n=1.0):
    """Diffuse reflectance per unit area at distance rho (Farrell 1992, Jensen et al. 2001)."""
    sigma_t = mua + mus_reduced
    alpha = mus_reduced / sigma_t
    sigma_tr = math.sqrt(3 * mua * sigma_t)
    f_dr = -1.440 / n**2 + 0.710 / n + 0.668 + 0.0636 * n
    a = (1 + f_dr) / (1 - f_dr)
    z_r = 1 / sigma_t
    z_v = z_r * (1 + 4 * a / 3)
    d_r, d_v = np.hypot(rho, z_r), np.hypot(rho, z_v)
    return alpha / (4 * math.pi) * (
        z_r * (1 + sigma_tr * d_r) * np.exp(-sigma_tr * d_r) / d_r**3
        + z_v * (1 + sigma_tr * d_v) * np.exp(-sigma_tr * d_v) / d_v**3)


def test_far_field_radial_profile_follows_the_diffusion_dipole_in_shape():
    mua, mus = 0.01, 1.0
    volume = np.zeros((1, 1, 1), np.uint8)
    photons = 300_000
    exits = trace_events(volume, *single_channel_tables([mua + mus], [mus / (mua + mus)], [0.0]),
                         optics(1.0, np.inf), False, 0.0, 0.0, photons, 3, 0, photons)
    rho = np.hypot(exits[:, 3] - exits[:, 1], exits[:, 4] - exits[:, 2])
    edges = np.linspace(4, 16, 9)
    weights, _ = np.histogram(rho, edges, weights=exits[:, 6])
    density = weights / (math.pi * np.diff(edges**2)) / photons
    centres = 0.5 * (edges[1:] + edges[:-1])
    ratio = density / farrell_dipole(centres, mua, mus)
    # Shape: the ratio is flat within 12 % over 4-16 mean free paths, while the profile itself
    # falls by a factor of about 30 there.
    assert farrell_dipole(4.0, mua, mus) / farrell_dipole(16.0, mua, mus) > 20
    assert np.all(np.abs(ratio / np.median(ratio) - 1) < 0.12), ratio


def homogeneous_scene(size=11, photons=400, max_radius=3.0, mua=0.2, mus=1.0, n=1.0, bins=200, depth=40):
    return parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": size, "width": size},
        "depth": depth, "n": n, "materials": {"m": {"mus": [mus] * 3, "mua": [mua, mua * 2, mua * 3]}},
        "background": "m", "photons_per_point": photons, "max_radius": max_radius,
        "path_length_bins": {"step": 1.0, "count": bins}, "seed": 5,
    })


@pytest.mark.parametrize("camera, view", [(False, (0, 0)), (True, (0, 0)), (True, (50, 120))])
def test_path_length_is_never_shorter_than_the_surface_distance(camera, view):
    """The paper's Eq. 3 lower bound, checked event by event in a layered medium with n = 1.4,
    for the exits and for the next-event paths toward a straight-down and an oblique camera."""
    scene = load_scene("layers3", size=(9, 9))
    channel = 1
    mu_t = np.array([m.mus[channel] + m.mua[channel] for m in scene.materials])
    albedo = np.array([m.mus[channel] for m in scene.materials]) / mu_t
    events = trace_events(scene.volume, *single_channel_tables(mu_t, albedo, np.zeros(3)),
                          optics(1.4, scene.depth, camera=view), camera, 4.0, 4.0, 5_000, 1, 0, 2_000_000)
    distance = np.hypot(events[:, 3] - events[:, 1], events[:, 4] - events[:, 2])
    assert len(events) > 1_000
    assert np.all(events[:, 5] >= distance - 1e-9)
    if view[0]:  # the oblique path to the camera leaves away from where it scattered
        assert distance.max() > 3


def test_impulse_reflectance_equals_the_sum_of_its_path_length_images():
    scene = homogeneous_scene(size=41, photons=3000, max_radius=20, mua=0.3, bins=400)
    transport_one = simulate_transport(scene, photons=3000, points=[[20, 20]], estimator="analogue")
    impulse_total = transport_one.windows[20, 20].sum(axis=(0, 1))
    truth_total = transport_one.path_length_images.sum(axis=(0, 1, 2))
    # Every exit lands inside both the window and the bins here (checked on the photons themselves).
    # The same photons, replayed one by one: point [20, 20]'s random stream is its grid index.
    # The scene's three channels share walks (same mus): channel 0 alone replays the same walk.
    tables, majorant = walk_tables([1.0], [[0.3], [0.6], [0.9]], [0.0])
    done = trace_events(scene.volume, tables, majorant, optics(1.0, scene.depth, uniform_mu_t=0.0), True, 20.0,
                        20.0, 3000, 5, 20 * 41 + 20, 1_000_000)
    assert np.abs(np.floor(done[:, 3:5] + 0.5) - 20).max() <= 20 and done[:, 5].max() < 400
    np.testing.assert_allclose(impulse_total, truth_total, rtol=1e-5)
    np.testing.assert_allclose(impulse_total, done[:, 6:9].sum(axis=0) / 3000, rtol=1e-5)


def test_simulation_is_deterministic_whatever_the_thread_count():
    scene = load_scene("red-bead", size=(10, 10))
    first = assert_same_for_any_thread_count(lambda: simulate_transport(scene, photons=60))
    other_seed = simulate_transport(scene, photons=60, seed=99)
    assert not np.array_equal(other_seed.windows, first.windows)


def test_a_run_of_some_points_fills_their_windows_as_a_run_of_every_point():
    # The analogue estimator walks each point on its own stream (seed, row-major grid index), so a
    # run restricted to some points (one named twice) gives their windows bit for bit as the
    # run of every point does, in the red bead or out of it, and leaves every other window 0.
    scene = load_scene("red-bead", size=(6, 6))
    every = simulate_transport(scene, photons=30, seed=4, estimator="analogue").windows
    some = simulate_transport(scene, photons=30, seed=4, estimator="analogue", points=[[4, 1], [2, 3], [4, 1]]).windows
    lit = np.zeros((6, 6), bool)
    lit[[4, 2], [1, 3]] = True
    assert np.array_equal(some[lit], every[lit]) and not np.array_equal(every[4, 1], every[2, 3])
    assert not some[~lit].any()


def test_written_dataset_holds_the_simulated_transport(tmp_path):
    scene = homogeneous_scene(size=12, photons=300, max_radius=2.5, n=1.4)
    transport = simulate_transport(scene)
    write_transport(transport, tmp_path / "ds")
    manifest = read_manifest(tmp_path / "ds")
    assert len(manifest.frames) == len(lattice_frames(12, 12, 2.5)) == 36  # spacing 6 on 12 x 12
    assert all(len(frame.lit) == 4 for frame in manifest.frames)
    assert len(manifest.ground_truth.path_length_images) == 200
    dataset = open_dataset(tmp_path / "ds")
    # E_0 at every point is its own pixel's light.
    e0 = ring_stack(dataset, [0.0]).images[0]
    centre = transport.windows[:, :, 3, 3]
    np.testing.assert_allclose(e0, centre, rtol=1e-6)
    # The manifest says what the frames hold, and states the specular reflection left out of them.
    assert simulated_measure(manifest) == "camera"
    assert "specular reflection 0.0277778 of the beam, not in the frames" in manifest.notes


def test_layered_scene_records_each_layer_with_a_reference_colour(tmp_path):
    scene = load_scene("layers3", size=(6, 6))
    write_transport(simulate_transport(scene, photons=20), tmp_path / "ds")
    layers = read_manifest(tmp_path / "ds").ground_truth.layers
    assert [layer.name for layer in layers] == ["yellow", "magenta", "blue"]  # the base is a layer too
    assert [layer.depth for layer in layers] == [(0.0, 2.0), (2.0, 5.0), (5.0, 24.0)]
    yellow, magenta, blue = (np.array(layer.rgb) for layer in layers)
    assert yellow[0] > yellow[2] and yellow[1] > yellow[2]
    assert magenta[0] > magenta[1] and magenta[2] > magenta[1]
    assert blue[2] > blue[1] > blue[0]


def test_an_interrupted_write_leaves_no_dataset(tmp_path):
    transport = simulate_transport(homogeneous_scene(size=8, photons=20))

    def cancel_midway(fraction):
        if fraction > 0.3:
            raise Cancelled("stop")

    with pytest.raises(Cancelled):
        write_transport(transport, tmp_path / "ds", progress=cancel_midway)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("change, needle", [
    (lambda s: s.update(background="steel"), "unknown material 'steel'"),
    (lambda s: s["materials"]["m"].update(mua=[0.1, -0.1, 0.1]), "negative coefficient"),
    (lambda s: s.update(shapes=[{"type": "sphere", "material": "m", "center": [4, 40, 2], "radius": 2}]), "outside the volume"),
    (lambda s: s.update(grid={"height": 4096, "width": 4096}), "fit in memory"),
    (lambda s: s.update(layers=[{"material": "m", "top": 3, "bottom": 1}]), "needs 0 <= top < bottom"),
    (lambda s: s.update(n=0.5), "refractive index"),
    (lambda s: s.update(measure="radiance"), "'measure' must be 'camera' or 'exitance', got 'radiance'"),
    (lambda s: s.update(camera={"direction": [95, 0]}), "'camera.direction' must be [zenith, azimuth]"),
    (lambda s: s.update(projector={"direction": [10]}), "'projector.direction' must be a list of 2 numbers"),
    (lambda s: s.update(camera={"zenith": 10}), "unknown key(s) 'zenith' in camera"),
])
def test_bad_scenes_are_refused_with_a_clear_message(change, needle):
    scene = {"format": "ringlight-scene", "version": 1, "grid": {"height": 8, "width": 8}, "depth": 8,
             "materials": {"m": {"mus": [1, 1, 1], "mua": [0.1, 0.1, 0.1]}}, "background": "m"}
    change(scene)
    with pytest.raises(SceneError, match="scene: ") as error:
        parse_scene(scene)
    assert needle in str(error.value)


@pytest.mark.parametrize("name", preset_names())
def test_every_preset_simulates_into_a_dataset_info_reads(tmp_path, name, capsys):
    assert main(["simulate", name, "--out", str(tmp_path / name), "--size", "8x8", "--photons", "10"]) == 0
    assert main(["info", str(tmp_path / name)]) == 0
    assert "grid         8 x 8" in capsys.readouterr().out


def test_simulate_cli_lists_presets_and_refuses_bad_arguments(tmp_path, capsys):
    assert main(["simulate", "--list"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in ["layers3", "red-bead", "star", "marble", "skin1", "wholemilk", "homogeneous"])
    assert main(["simulate", "layers3", "--out", str(tmp_path / "x"), "--size", "big"]) == 2
    assert "--size 'big' must be HxW" in capsys.readouterr().err
    assert main(["simulate", "nosuch", "--out", str(tmp_path / "x")]) == 2
    assert "neither a preset" in capsys.readouterr().err


def test_simulate_list_keeps_its_columns_for_long_names(tmp_path, capsys, monkeypatch):
    """Issue 39: "layers-reversed" (15 characters) ran into its notes in a 12-character column.
    Every preset's notes start in one column, after at least two spaces, and wrapped lines stay
    under it within the terminal's width."""
    monkeypatch.setenv("COLUMNS", "90")
    assert main(["simulate", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = preset_names()
    column = max(len(name) for name in names) + 2
    starts = [line for line in lines if not line.startswith(" ")]
    assert [line.split()[0] for line in starts] == names
    for line in lines:
        assert len(line) <= 90, line
        assert line[column - 2:column] == "  " and line[column] != " ", line
    for name, line in zip(names, starts):
        assert line[column:].startswith(preset_notes(name)[:20])


def test_the_seed_actually_used_is_recorded_in_the_dataset(tmp_path):
    transport = simulate_transport(homogeneous_scene(size=6, photons=10), seed=7)
    write_transport(transport, tmp_path / "ds")
    assert transport.seed == 7
    assert "seed 7," in read_manifest(tmp_path / "ds").notes
