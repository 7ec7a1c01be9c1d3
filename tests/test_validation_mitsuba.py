"""The simulator's frames against an independent projector-camera render (Mitsuba 3's volpath).

Both renderers see the same slab (mus 6, mua 0.5 per mm, g 0, pitch 0.1 mm, 2 mm deep) lit
by a unit-power collimated beam over one pixel, and both report the reflectance factor toward
the camera (FORMAT.md "What a simulated frame holds"); tests/mitsuba_rig.py describes the
render. Radial profiles (mean over the pixels at |d| in [r - 0.5, r + 0.5)) must agree within
3 combined standard errors at r = 0..4, in absolute units. Mitsuba's errors come from each
pixel's second moment; ringlight's from the spread of independently seeded batches.
"""

import math

import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="Mitsuba 3 renders the reference frames: pip install 'ringlight[validation]'")

import mitsuba_rig as rig  # needs mitsuba, hence after the skip
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import simulate_transport

MUS_MM, MUA_MM, PITCH_MM = 6.0, 0.5, 0.1
DEPTH = 20.0
"""Grid steps: the same finite slab in both renderers (light reaching the bottom is lost)."""
RADII = range(5)
WINDOW = 4
"""Ringlight's max_radius and the Mitsuba image's half size: the rings up to r = 4 fit."""
SPP = 32768
BATCHES = 32
"""Independently seeded ringlight runs per estimate (31 degrees of freedom for its error)."""
PROFILE_PHOTONS, SUM_PHOTONS = 8000, 2000


def slab(n: float) -> rig.Slab:
    return rig.Slab(mus=MUS_MM * PITCH_MM, mua=MUA_MM * PITCH_MM, g=0.0, n=n, depth=DEPTH)


def ringlight_scene(n: float, radius: int, camera=(0.0, 0.0), projector=(0.0, 0.0), measure="camera"):
    size = 2 * radius + 1
    return parse_scene({
        "format": "ringlight-scene", "version": 1,
        "grid": {"height": size, "width": size, "pitch_mm": PITCH_MM}, "depth": DEPTH, "n": n,
        "materials": {"slab": {"mus": [MUS_MM] * 3, "mua": [MUA_MM] * 3, "g": 0.0}},
        "background": "slab", "max_radius": radius,
        "camera": {"direction": list(camera)}, "projector": {"direction": list(projector)},
        "measure": measure,
        # The frames do not depend on the path-length bins (the same windows bit for bit): one bin
        # spares the path-length tally, never read here, which at max_radius 25 is (bins, 101,
        # 101, 3) per run and cost most of a 2000-photon run (64 bins: 0.14 CPU-s a run, 1: 0.03).
        "path_length_bins": {"step": 1.0, "count": 1},
    })


def ringlight_frames(scene, photons: int, batches: int, first_seed: int) -> np.ndarray:
    """(batches, 2R+1, 2R+1) frames of the centre pixel, one independent seed per batch."""
    radius = math.ceil(scene.max_radius)
    return np.stack([
        simulate_transport(scene, photons=photons, seed=first_seed + batch,
                           points=[[radius, radius]]).windows[radius, radius, :, :, 0].astype(np.float64)
        for batch in range(batches)])


def mean_and_error(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over the first axis and its standard error."""
    return samples.mean(axis=0), samples.std(axis=0, ddof=1) / math.sqrt(len(samples))


def compare_profiles(n: float, camera=(0.0, 0.0), projector=(0.0, 0.0), seed: int = 0) -> str:
    """Assert that both radial profiles agree; returns the per-radius report."""
    render = rig.render_impulse(slab(n), camera=camera, projector=projector, size=2 * WINDOW + 1,
                                spp=SPP, seed=seed)
    reference, reference_error = rig.radial_profile(render.image, render.standard_error, RADII)
    frames = ringlight_frames(ringlight_scene(n, WINDOW, camera, projector), PROFILE_PHOTONS, BATCHES,
                              100 * seed)
    profile, profile_error = mean_and_error(
        np.array([rig.radial_profile(frame, radii=RADII)[0] for frame in frames]))
    combined = np.hypot(reference_error, profile_error)
    report = "\n".join(
        f"r={r}: mitsuba {m:.5f} +- {me:.5f}, ringlight {s:.5f} +- {se:.5f}, {(s - m) / c:+.1f} sigma"
        f" of {c / m:.1%}"
        for r, m, me, s, se, c in zip(RADII, reference, reference_error, profile, profile_error, combined))
    assert np.all(np.abs(profile - reference) < 3 * combined), report
    # The check means something only if 3 standard errors are small against the values.
    assert np.all(combined < 0.05 * reference), report
    return report


def test_the_rig_reads_a_white_lambertian_surface_as_one_at_the_lit_pixel():
    # FORMAT.md: "A white Lambertian surface would read 1 at the lit pixel and 0 elsewhere";
    # this checks the projector's power, the footprint of an oblique beam and of an oblique
    # camera's pixels, and the conversion to the reflectance factor.
    expected = np.zeros((3, 3))
    expected[1, 1] = 1.0
    for camera, projector in [((0, 0), (0, 0)), ((30, 0), (0, 0)), ((30, 90), (0, 0)), ((0, 0), (60, 0)),
                              ((45, 30), (60, 120))]:
        render = rig.render_white_patch(camera, projector, size=3, spp=64)
        np.testing.assert_allclose(render.image, expected, atol=1e-4, err_msg=f"{camera} {projector}")


@pytest.mark.parametrize("n", [1.0, 1.4])
def test_the_rig_renders_single_scattering_as_its_analytic_value(n):
    # Light scattered once from a beam straight down, seen straight down, stays in the lit
    # pixel: pi x radiance = (1 - F)^2 / n^2 x albedo / 8 x (1 - exp(-2 mu_t depth)) per unit
    # irradiance (isotropic phase 1 / (4 pi); the depth integral of exp(-2 mu_t z) mu_s;
    # Fresnel in and out at normal incidence; radiance / n^2 is conserved across the surface).
    medium = slab(n)
    mu_t = medium.mus + medium.mua
    fresnel = ((n - 1) / (n + 1)) ** 2
    expected = (1 - fresnel) ** 2 / n**2 * medium.mus / mu_t / 8 * (1 - math.exp(-2 * mu_t * DEPTH))
    # volpath counts the refraction into a dielectric as one bounce and the scattering as one.
    render = rig.render_impulse(medium, size=3, spp=16384, seed=5 if n == 1 else 6,
                                max_depth=2 if n == 1 else 3)
    lit = render.image[1, 1]
    assert abs(lit - expected) < 3 * render.standard_error[1, 1], (lit, render.standard_error[1, 1], expected)
    assert render.standard_error[1, 1] < 0.01 * expected
    # Only the projector's divergence (at most 0.0007 rad) moves light to the neighbours:
    # about 4e-4 of it to each, a few samples' worth.
    assert np.delete(render.image.ravel(), 4).max() < 3e-3 * expected


def test_index_matched_slab_matches_mitsuba():
    compare_profiles(1.0, seed=1)


def test_refractive_slab_matches_mitsuba():
    compare_profiles(1.4, seed=2)


def test_oblique_camera_over_a_refractive_slab_matches_mitsuba():
    compare_profiles(1.4, camera=(30.0, 0.0), seed=3)


def test_oblique_projector_over_an_index_matched_slab_matches_mitsuba():
    # An oblique beam through a refractive surface has no exact Mitsuba counterpart here (see
    # tests/mitsuba_rig.py), so the oblique projector is checked at n = 1.
    compare_profiles(1.0, projector=(60.0, 0.0), seed=4)


@pytest.mark.parametrize("n", [1.0, 1.4])
def test_a_straight_down_frame_sums_to_the_normal_in_normal_out_reflectance_factor(n):
    # Linearity and translation invariance: a uniform beam's frame is the sum over the plane of
    # one lit pixel's frame. Mitsuba renders the uniform beam directly; ringlight's frame is
    # summed over a window wide enough (25 steps, 8 diffusion lengths) to miss less than 1e-4
    # of it (diffusion dipole, Farrell et al. 1992).
    uniform = rig.render_uniform(slab(n), size=3, spp=SPP // 4, seed=10 + int(10 * n))
    reference = uniform.image.mean()
    reference_error = math.sqrt((uniform.standard_error**2).sum()) / uniform.image.size
    radius = 25
    sums, sum_error = mean_and_error(
        ringlight_frames(ringlight_scene(n, radius), SUM_PHOTONS, BATCHES, 1000).sum(axis=(1, 2)))
    combined = math.hypot(reference_error, sum_error)
    assert abs(sums - reference) < 3 * combined, (sums, sum_error, reference, reference_error)
    if n == 1.0:
        # Like with like: summed over the plane, an index-matched slab lit straight down is
        # brighter at grazing angles than a Lambertian surface (Chandrasekhar's reflection
        # function goes as 1 / (mu + mu_0)), so its total diffuse reflectance (all exit
        # directions) is another number, 6 % higher. (Under n = 1.4 the two nearly agree.)
        totals, total_error = mean_and_error(ringlight_frames(
            ringlight_scene(n, radius, measure="exitance"), SUM_PHOTONS, BATCHES, 2000).sum(axis=(1, 2)))
        assert abs(totals - reference) > 5 * math.hypot(reference_error, total_error), (totals, reference)
