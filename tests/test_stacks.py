"""Ring light and transient stacks against brute force over FORMAT.md's definitions."""

import functools
from types import SimpleNamespace

import numpy as np
import pytest
from numpy.testing import assert_allclose
from reference import (
    brute_ring_image,
    random_impulses,
    supersampled_annulus_weight,
    write_dataset,
    write_rgb,
)
from ringlight.core import (
    StackError,
    disc_offsets,
    annulus_pixel_area,
    open_dataset,
    radius_range,
    ring_stack,
    transient_stack,
)


def assert_same_with_nan(actual, expected, rtol=1e-5, atol=1e-6):
    assert np.array_equal(np.isnan(actual), np.isnan(expected)), "NaN in different places"
    assert_allclose(np.nan_to_num(actual), np.nan_to_num(expected), rtol=rtol, atol=atol)


@pytest.mark.parametrize(
    "height, width, missing, seed",
    [(9, 9, 0.0, 0), (7, 13, 0.15, 1), (12, 5, 0.3, 2), (1, 11, 0.0, 3)],
)
def test_transient_stack_equals_brute_force_on_random_datasets(tmp_path, height, width, missing, seed):
    rng = np.random.default_rng(seed)
    impulses = random_impulses(rng, height, width, support=40, missing=missing)
    write_dataset(tmp_path / "ds", height, width, impulses)
    dataset = open_dataset(tmp_path / "ds", radius=6.5)
    radii = radius_range(0, 5, 1)
    stack = transient_stack(dataset, radii, step=1.0)
    for index, radius in enumerate(radii):
        inner = brute_ring_image(impulses, height, width, radius)
        outer = brute_ring_image(impulses, height, width, radius + 1)
        assert_same_with_nan(stack.images[index], inner - outer)
    assert dataset.missing_count == height * width - len(impulses)



def test_a_datasets_rows_are_read_only_as_assembled_and_as_read_from_its_store(tmp_path):
    """Opened the first time a dataset is assembled in memory (writeable), its store written and
    kept; opened again it is read from its store. Its rows are read-only either way, and its array
    untouched, so that the stack's kernel is compiled for read-only responses only (numba compiled
    it once for each, 3-6 s on a fresh install; the stacks are the same)."""
    from ringlight.core.rings.stacks import _ring_sums

    rng = np.random.default_rng(3)
    impulses = random_impulses(rng, 6, 7, support=20)
    write_dataset(tmp_path / "ds", 6, 7, impulses)
    assembled, stored = open_dataset(tmp_path / "ds", radius=3), open_dataset(tmp_path / "ds", radius=3)
    assert assembled.store is not None and stored.store is not None
    assert assembled.responses.flags.writeable
    for dataset in (assembled, stored):
        assert not dataset.rows(0, 6).flags.writeable and not dataset.rows(2, 3).flags.writeable
    np.testing.assert_array_equal(ring_stack(assembled, [0, 1, 2]).images, ring_stack(stored, [0, 1, 2]).images)
    assert assembled.responses.flags.writeable
    assert _ring_sums.signatures and all(not signature[0].mutable for signature in _ring_sums.signatures)

def test_ring_counts_are_the_number_of_lit_in_grid_members(tmp_path):
    rng = np.random.default_rng(5)
    impulses = random_impulses(rng, 8, 10, support=20, missing=0.2)
    write_dataset(tmp_path / "ds", 8, 10, impulses)
    stack = ring_stack(open_dataset(tmp_path / "ds", radius=4), [0, 1.5, 3])
    for index, radius in enumerate([0, 1.5, 3]):
        for y in range(8):
            for x in range(10):
                expected = sum(
                    1 for (qy, qx) in impulses
                    if radius - 0.5 <= np.hypot(qy - y, qx - x) < radius + 0.5
                )
                assert stack.counts[index, y, x] == expected


def test_fractional_radii_thickness_and_step_match_brute_force(tmp_path):
    rng = np.random.default_rng(7)
    impulses = random_impulses(rng, 10, 10, support=40, missing=0.1)
    write_dataset(tmp_path / "ds", 10, 10, impulses)
    dataset = open_dataset(tmp_path / "ds", radius=8)
    radii = np.array([0.3, 1.7, 2.5])
    stack = transient_stack(dataset, radii, step=0.75, thickness=2.5)
    for index, radius in enumerate(radii):
        expected = (brute_ring_image(impulses, 10, 10, radius, 2.5)
                    - brute_ring_image(impulses, 10, 10, radius + 0.75, 2.5))
        assert_same_with_nan(stack.images[index], expected)


def test_antialiased_stack_equals_area_weighted_brute_force(tmp_path):
    rng = np.random.default_rng(11)
    impulses = random_impulses(rng, 9, 9, support=40, missing=0.1)
    write_dataset(tmp_path / "ds", 9, 9, impulses)
    dataset = open_dataset(tmp_path / "ds", radius=7)
    stack = ring_stack(dataset, [0.0, 2.2, 4.0], thickness=1.0, antialias=True)
    for index, radius in enumerate([0.0, 2.2, 4.0]):
        inner, outer = max(radius - 0.5, 0.0), radius + 0.5
        # Each offset's area once (cached), not once per pixel and lit point: 17 700 exact areas took 6 CPU-s.
        expected = brute_ring_image(
            impulses, 9, 9, radius,
            weight=functools.cache(lambda dy, dx: float(annulus_pixel_area(dy, dx, inner, outer))),
        )
        assert_same_with_nan(stack.images[index], expected)
        # The exact areas agree with 64 x 64 supersampling to its resolution.
        sampled = brute_ring_image(impulses, 9, 9, radius, weight=supersampled_annulus_weight(radius, 1.0))
        assert_allclose(np.nan_to_num(stack.images[index]), np.nan_to_num(sampled), rtol=0.02, atol=2e-3)


def test_multiplexed_frames_equal_single_impulses(tmp_path):
    rng = np.random.default_rng(3)
    height, width, max_radius = 20, 17, 3.0
    impulses = random_impulses(rng, height, width, support=max_radius, missing=0.1)
    write_dataset(tmp_path / "single", height, width, impulses)
    manifest = write_dataset(tmp_path / "multi", height, width, impulses, max_radius=max_radius, multiplex=True)
    assert len(manifest["frames"]) == 49  # a 7 x 7 lattice of spacing 2 * max_radius + 1
    single = open_dataset(tmp_path / "single", radius=max_radius)
    multi = open_dataset(tmp_path / "multi")
    radii = radius_range(0, 2, 0.5)
    a = transient_stack(single, radii, step=0.5)
    b = transient_stack(multi, radii, step=0.5)
    assert_same_with_nan(b.images, a.images)
    expected = (brute_ring_image(impulses, height, width, 1.5)
                - brute_ring_image(impulses, height, width, 2.0))
    assert_same_with_nan(b.images[3], expected)


def test_camera_frames_with_2x2_mapping_equal_grid_frames(tmp_path):
    rng = np.random.default_rng(4)
    height, width = 8, 9
    impulses = random_impulses(rng, height, width, support=30, missing=0.1)
    write_dataset(tmp_path / "grid", height, width, impulses)
    # Camera of 2H+3 x 2W+2 pixels: each grid point seen by 2 x 2 pixels whose mapped positions
    # are jittered by < 0.5 (so they round back), a border that sees nothing (NaN), and pixel
    # values g * (1 + e) with e summing to zero over the four, so their mean is g.
    cam_h, cam_w = 2 * height + 3, 2 * width + 2
    cy, cx = np.mgrid[:cam_h, :cam_w]
    gy, gx = (cy - 1) // 2, (cx - 1) // 2
    inside = (cy >= 1) & (gy < height) & (cx >= 1) & (gx < width)
    map_y = np.where(inside, gy + rng.uniform(-0.45, 0.45, cy.shape), np.nan)
    map_x = np.where(inside, gx + rng.uniform(-0.45, 0.45, cy.shape), np.nan)
    pattern = np.array([[0.2, -0.1], [0.3, -0.4]])[(cy - 1) % 2, (cx - 1) % 2]
    folder = tmp_path / "camera"
    from reference import write_exr
    write_exr(folder / "mapping.exr", {"y": map_y, "x": map_x})
    frames = []
    for index, (q, image) in enumerate(sorted(impulses.items())):
        camera = np.where(inside[..., None], image[np.clip(gy, 0, height - 1), np.clip(gx, 0, width - 1)], 77.0)
        camera = camera * (1 + pattern[..., None])
        write_rgb(folder / f"frames/{index}.exr", camera.astype(np.float32))
        frames.append({"file": f"frames/{index}.exr", "lit": [list(q)]})
    import json
    (folder / "dataset.json").write_text(json.dumps({
        "format": "ringlight-impulse", "version": 1, "grid": {"height": height, "width": width},
        "frame_space": "camera", "mapping": "mapping.exr", "frames": frames,
    }))
    radii = radius_range(0, 4, 1)
    a = transient_stack(open_dataset(tmp_path / "grid", radius=6), radii)
    b = transient_stack(open_dataset(folder, radius=6), radii)
    assert_same_with_nan(b.images, a.images, rtol=1e-5, atol=1e-6)


def test_unobserved_camera_grid_points_are_nan(tmp_path):
    import json

    from reference import write_exr
    folder = tmp_path / "ds"
    map_y, map_x = np.mgrid[:4, :4].astype(np.float32)
    map_y[1, 2] = np.nan  # grid point [1, 2] is seen by no camera pixel
    write_exr(folder / "mapping.exr", {"y": map_y, "x": map_x})
    frames = []
    for y in range(4):
        for x in range(4):
            write_rgb(folder / f"f{y}{x}.exr", np.ones((4, 4, 3), np.float32))
            frames.append({"file": f"f{y}{x}.exr", "lit": [[y, x]]})
    (folder / "dataset.json").write_text(json.dumps({
        "format": "ringlight-impulse", "version": 1, "grid": {"height": 4, "width": 4},
        "frame_space": "camera", "mapping": "mapping.exr", "frames": frames}))
    dataset = open_dataset(folder)
    stack = ring_stack(dataset, [1.0])
    assert np.isnan(stack.images[0, 1, 2]).all()
    assert np.isfinite(stack.images[0][dataset.observed]).all()
    assert dataset.observed.sum() == 15


def test_dark_frame_exposure_and_repeated_points_are_applied(tmp_path):
    """radiance = frame / exposure - dark, and a point lit in two frames gets the mean."""
    import json
    folder = tmp_path / "ds"
    rng = np.random.default_rng(9)
    dark = rng.uniform(0, 0.1, (5, 6, 3)).astype(np.float32)
    write_rgb(folder / "dark.exr", dark)
    truth, frames = {}, []
    for index, (y, x) in enumerate([(y, x) for y in range(5) for x in range(6)]):
        truth[(y, x)] = rng.uniform(0, 1, (5, 6, 3)).astype(np.float32)
        exposure = [0.5, 1.0, 4.0][index % 3]
        write_rgb(folder / f"{index}.exr", (truth[(y, x)] + dark) * exposure)
        frames.append({"file": f"{index}.exr", "lit": [[y, x]], "exposure": exposure})
    # Point [2, 3] lit again with a different response: the dataset must average the two.
    second = rng.uniform(0, 1, (5, 6, 3)).astype(np.float32)
    write_rgb(folder / "again.exr", (second + dark) * 2.0)
    frames.append({"file": "again.exr", "lit": [[2, 3]], "exposure": 2.0})
    truth[(2, 3)] = (truth[(2, 3)] + second) / 2
    (folder / "dataset.json").write_text(json.dumps({
        "format": "ringlight-impulse", "version": 1, "grid": {"height": 5, "width": 6},
        "dark": "dark.exr", "frames": frames}))
    dataset = open_dataset(folder, radius=3)
    assert dataset.lit_counts[2, 3] == 2
    stack = ring_stack(dataset, [0, 1, 2])
    for index, radius in enumerate([0, 1, 2]):
        assert_same_with_nan(stack.images[index], brute_ring_image(truth, 5, 6, radius), rtol=1e-4, atol=1e-5)


def test_a_disc_of_more_offsets_than_int16_holds_assembles_like_brute_force(tmp_path):
    """The assembly marks each point's offset slot (offsets in raster order) in int16 while the
    disc has at most 32 767 offsets, in int32 beyond (max_radius 103 and more): rings near
    max_radius on a grid as tall take the last slots. A point lit twice is averaged there too."""
    import json
    rng = np.random.default_rng(21)
    height, width = 106, 1
    impulses = {(y, x): rng.uniform(0.2, 1.0, (height, width, 3)).astype(np.float32)
                for y in range(height) for x in range(width)}
    write_dataset(tmp_path / "ds", height, width, impulses, max_radius=104)
    manifest = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    again = rng.uniform(0, 1, (height, width, 3)).astype(np.float32)
    write_rgb(tmp_path / "ds" / "again.exr", again)
    manifest["frames"].append({"file": "again.exr", "lit": [[104, 0]]})
    (tmp_path / "ds" / "dataset.json").write_text(json.dumps(manifest))
    impulses[(104, 0)] = (impulses[(104, 0)] + again) / 2
    dataset = open_dataset(tmp_path / "ds")
    assert len(dataset.offsets) > np.iinfo(np.int16).max
    radii = [0, 2, 103]
    stack = ring_stack(dataset, radii)
    for index, radius in enumerate(radii):
        assert_same_with_nan(stack.images[index], brute_ring_image(impulses, height, width, radius),
                             rtol=1e-4, atol=1e-5)


def test_half_float_frames_read_like_float_frames(tmp_path):
    rng = np.random.default_rng(12)
    impulses = random_impulses(rng, 6, 6, support=10)
    impulses = {q: image.astype(np.float16).astype(np.float32) for q, image in impulses.items()}
    write_dataset(tmp_path / "half", 6, 6, impulses, half=True)
    write_dataset(tmp_path / "float", 6, 6, impulses)
    a = ring_stack(open_dataset(tmp_path / "half", radius=3), [0, 1, 2])
    b = ring_stack(open_dataset(tmp_path / "float", radius=3), [0, 1, 2])
    assert_same_with_nan(a.images, b.images, rtol=0, atol=0)


def test_ring_light_at_every_radius_shares_computation(tmp_path):
    """T_r uses E_r and E_{r+dr} computed once: a transient stack equals differences of a ring stack."""
    rng = np.random.default_rng(13)
    impulses = random_impulses(rng, 7, 7, support=20)
    write_dataset(tmp_path / "ds", 7, 7, impulses)
    dataset = open_dataset(tmp_path / "ds", radius=6)
    rings = ring_stack(dataset, radius_range(0, 5, 1))
    transients = transient_stack(dataset, radius_range(0, 4, 1), step=1)
    assert_same_with_nan(transients.images, rings.images[:-1] - rings.images[1:], rtol=0, atol=0)
    assert np.array_equal(transients.outer_counts, rings.counts[1:])


def test_steady_state_and_impulse_image_read_back_the_impulses(tmp_path):
    rng = np.random.default_rng(14)
    impulses = random_impulses(rng, 6, 7, support=3, missing=0.2)
    write_dataset(tmp_path / "ds", 6, 7, impulses)
    dataset = open_dataset(tmp_path / "ds", radius=3)
    assert_allclose(dataset.steady_state(), sum(impulses.values()), rtol=1e-5, atol=1e-6)
    (qy, qx), image = next(iter(impulses.items()))
    assert_allclose(np.nan_to_num(dataset.impulse_image(qy, qx)), image, rtol=1e-6)


def test_ring_beyond_max_radius_is_refused_with_the_limit_named(tmp_path):
    rng = np.random.default_rng(15)
    impulses = random_impulses(rng, 12, 12, support=3)
    write_dataset(tmp_path / "ds", 12, 12, impulses, max_radius=3, multiplex=True)
    dataset = open_dataset(tmp_path / "ds")
    with pytest.raises(StackError, match="beyond the dataset's max_radius 3"):
        transient_stack(dataset, [2.0, 3.0], step=1.0)


def test_a_ring_beyond_max_radius_names_the_dataset_and_the_radii_that_work(tmp_path):
    """The refusal names the dataset's folder and the largest requested radius whose rings fit
    (issue 39: README's 0:20:1 failed on every sample without saying what would work)."""
    rng = np.random.default_rng(16)
    impulses = random_impulses(rng, 12, 12, support=3)
    write_dataset(tmp_path / "ds", 12, 12, impulses, max_radius=3, multiplex=True)
    dataset = open_dataset(tmp_path / "ds")

    def fits(radius):  # brute force: every offset of the default ring (|d| < radius + 1/2) is within 3
        span = np.arange(-8, 9)
        distance = np.hypot(*np.meshgrid(span, span))
        return bool((distance[distance < radius + 0.5] <= 3).all())

    radii = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    transient_best = max(r for r in radii if fits(r + 0.5))
    ring_best = max(r for r in radii if fits(r))
    assert (transient_best, ring_best) == (2.0, 2.5)  # sqrt(10) = 3.16 > 3 from |d| < 3.5 on
    with pytest.raises(StackError) as refused:
        transient_stack(dataset, radii, step=0.5)
    message = refused.value.args[0]
    assert str(tmp_path / "ds") in message and "beyond the dataset's max_radius 3" in message
    assert f"up to {transient_best:g} work (radii 0:{transient_best:g}:0.5)" in message
    with pytest.raises(StackError, match=f"ring radii up to {ring_best:g} work"):
        ring_stack(dataset, radii)
    with pytest.raises(StackError, match="no transient radii \\(dr 0.5\\) of those requested work"):
        transient_stack(dataset, [3.0, 2.5], step=0.5)
    assert transient_stack(dataset, radius_range(0, transient_best, 0.5), step=0.5).images.shape[0] == 5


@pytest.mark.parametrize("antialias", [False, True])
def test_ring_members_of_a_band_equal_the_sums_of_its_validity_flags(antialias):
    """The members counted from the lit mask (whole rows at once) against a sum over the
    dataset's per-offset validity flags, for a band that starts inside the grid and with
    unobserved and missing points."""
    from ringlight.core.rings.members import ring_members, unit_weight_rings
    from ringlight.core.rings.stacks import _ring_tables

    rng = np.random.default_rng(11)
    height, width, row0, row1 = 13, 9, 4, 11
    lit = rng.random((height, width)) > 0.25
    observed = rng.random((height, width)) > 0.1
    offsets = disc_offsets(4.0)
    radii = np.array([0.0, 1.0, 1.7, 2.5, 3.0])
    tables = _ring_tables(SimpleNamespace(offsets=offsets, max_radius=4.0), radii, 1.0, antialias)
    counts, totals = ring_members(lit, observed, offsets, tables, unit_weight_rings(tables), row0, row1)
    validity = np.zeros((row1 - row0, width, len(offsets)))
    for y in range(row0, row1):
        for x in range(width):
            for k, (dy, dx) in enumerate(offsets):
                qy, qx = y + dy, x + dx
                validity[y - row0, x, k] = observed[y, x] and 0 <= qy < height and 0 <= qx < width and lit[qy, qx]
    first, stop, weight_start, weights = tables
    for j in range(len(radii)):
        ring = np.zeros(len(offsets))
        ring[first[j]:stop[j]] = weights[weight_start[j]:weight_start[j + 1]]
        assert np.array_equal(counts[j], (validity * (ring > 0)).sum(-1))
        assert_allclose(totals[j], validity @ ring, rtol=1e-12)
        assert counts[j].max() > 0


def test_a_ring_holding_no_grid_offset_is_undefined_not_an_error(tmp_path):
    """Radius 0.5 at thickness 0.5 holds no offset (0.25 <= |d| < 0.75): its ring light image is
    NaN with no member, as the definition's brute force gives, and the stacks of the other radii
    are unchanged (found by a review: a traceback from an empty reduction)."""
    impulses = random_impulses(np.random.default_rng(5), 8, 9, support=10)
    write_dataset(tmp_path / "ds", 8, 9, impulses)
    dataset = open_dataset(tmp_path / "ds", radius=6)
    stack = ring_stack(dataset, [0.5, 1.5, 3.0], thickness=0.5)
    assert (stack.counts[0] == 0).all()
    for index, radius in enumerate([0.5, 1.5, 3.0]):
        assert_same_with_nan(stack.images[index], brute_ring_image(impulses, 8, 9, radius, thickness=0.5))
    assert np.isnan(stack.images[0]).all() and not np.isnan(stack.images[2]).all()
    transient = transient_stack(dataset, [0.5, 2.0], 1.0, thickness=0.5)
    assert np.isnan(transient.images[0]).all()
    assert_same_with_nan(transient.images[1], brute_ring_image(impulses, 8, 9, 2.0, thickness=0.5)
                         - brute_ring_image(impulses, 8, 9, 3.0, thickness=0.5))
