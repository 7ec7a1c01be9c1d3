"""Datasets from any rig (FORMAT.md "Frame files", issue 19): monochrome `Y` frames, prefixed
channel names, multi-part and tiled mip-mapped frames, chromaticities and `colorspace` given as
primaries or a matrix. Each opens and gives the stacks of the same impulses written as plain
R, G, B frames; what FORMAT.md refuses is refused with one line naming the file and both values."""

import json

import numpy as np
import OpenEXR
import pytest
from plain_view import plain_settings
from exr_corpus import ACES_AP0, complete_mipmap, tiles, write_deep
from reference import brute_ring_image, edit_manifest, random_impulses, write_dataset
from ringlight.app.main import main
from ringlight.core import DatasetError, open_dataset, read_stack, ring_stack, transient_stack
from ringlight.core.colour.chroma import chromaticity, colour_unavailable
from ringlight.core.colour.display import DisplaySettings, render
from ringlight.core.colourspaces import colour_module

HEIGHT, WIDTH = 7, 6
RADII = np.arange(0, 5.0)


@pytest.fixture
def grey_impulses():
    """Impulse images with R = G = B: what a monochrome camera and its RGB twin both record."""
    impulses = random_impulses(np.random.default_rng(4), HEIGHT, WIDTH, support=4, missing=0.1)
    return {q: np.repeat(image[..., 1:2], 3, axis=-1) for q, image in impulses.items()}


@pytest.fixture
def colour_impulses():
    return random_impulses(np.random.default_rng(5), HEIGHT, WIDTH, support=4)


def rewrite_frames(folder, make_file):
    """Rewrite every frame of ``folder`` as ``make_file(path, (H, W, 3) image)`` would write it."""
    manifest = json.loads((folder / "dataset.json").read_text())
    for frame in manifest["frames"]:
        path = folder / frame["file"]
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            image = np.stack([np.asarray(exr.channels()[c].pixels) for c in "RGB"], -1)
        make_file(path, image)


def write_header(path, channels, **header):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **header}
    with OpenEXR.File(header, {name: np.ascontiguousarray(plane) for name, plane in channels.items()}) as exr:
        exr.write(str(path))


def stacks(folder, **options):
    dataset = open_dataset(folder, radius=6, use_cache=False, **options)
    return dataset, transient_stack(dataset, RADII, 1.0).images, ring_stack(dataset, RADII).images


def test_a_monochrome_y_dataset_equals_its_grey_rgb_twin(tmp_path, grey_impulses):
    write_dataset(tmp_path / "rgb", HEIGHT, WIDTH, grey_impulses)
    write_dataset(tmp_path / "mono", HEIGHT, WIDTH, grey_impulses)
    rewrite_frames(tmp_path / "mono", lambda path, image: write_header(path, {"Y": image[..., 0]}))
    rgb, rgb_transients, rgb_rings = stacks(tmp_path / "rgb")
    mono, mono_transients, mono_rings = stacks(tmp_path / "mono")
    assert mono.monochrome and mono.channels == ("Y",) and not rgb.monochrome
    np.testing.assert_array_equal(mono_transients, rgb_transients)
    np.testing.assert_array_equal(mono_rings, rgb_rings)
    # FORMAT.md's definition, by brute force: E_2 of the grey impulses.
    np.testing.assert_allclose(mono_rings[2], brute_ring_image(grey_impulses, HEIGHT, WIDTH, 2.0), rtol=1e-5)
    pixels = render(mono_rings[2], (0.0, float(np.nanmax(mono_rings[2]))), DisplaySettings(), mono.colorspace)
    assert (pixels[..., 0] == pixels[..., 1]).all() and (pixels[..., 1] == pixels[..., 2]).all()  # grey


def test_a_monochrome_dataset_with_a_y_dark_frame_and_named_channel(tmp_path, grey_impulses):
    write_dataset(tmp_path / "rgb", HEIGHT, WIDTH, grey_impulses)
    write_dataset(tmp_path / "mono", HEIGHT, WIDTH, grey_impulses)
    rewrite_frames(tmp_path / "mono", lambda path, image: write_header(path, {"L": image[..., 0] + 0.25}))
    write_header(tmp_path / "mono" / "dark.exr", {"L": np.full((HEIGHT, WIDTH), 0.25, np.float32)})
    edit_manifest(tmp_path / "mono", lambda m: m.update(channels=["L"], dark="dark.exr"))
    _, rgb_transients, _ = stacks(tmp_path / "rgb")
    _, mono_transients, _ = stacks(tmp_path / "mono")
    np.testing.assert_allclose(mono_transients, rgb_transients, atol=1e-6)


@pytest.mark.parametrize("prefix", ["camera.", "ViewLayer.Combined."])
def test_prefixed_channels_read_as_the_plain_dataset(tmp_path, colour_impulses, prefix):
    write_dataset(tmp_path / "rgb", HEIGHT, WIDTH, colour_impulses)
    write_dataset(tmp_path / "named", HEIGHT, WIDTH, colour_impulses)
    names = [prefix + c for c in "RGB"]
    rewrite_frames(tmp_path / "named", lambda path, image: write_header(
        path, {name: image[..., i] for i, name in enumerate(names)} | {prefix + "A": image[..., 0]}))
    with pytest.raises(DatasetError, match=r"read them with \"channels\": \[.*\] in the manifest"):
        open_dataset(tmp_path / "named", radius=6, use_cache=False)
    edit_manifest(tmp_path / "named", lambda m: m.update(channels=names))
    np.testing.assert_array_equal(stacks(tmp_path / "named")[1], stacks(tmp_path / "rgb")[1])


def test_tiled_mip_mapped_and_multi_part_frames_read_as_the_plain_dataset(tmp_path, colour_impulses):
    write_dataset(tmp_path / "rgb", HEIGHT, WIDTH, colour_impulses)
    write_dataset(tmp_path / "tiled", HEIGHT, WIDTH, colour_impulses)
    write_dataset(tmp_path / "parts", HEIGHT, WIDTH, colour_impulses)

    def tiled(path, image):
        channels = {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}
        write_header(path, channels, type=OpenEXR.tiledimage, tiles=tiles(OpenEXR.MIPMAP_LEVELS, 4, 2),
                     compression=OpenEXR.NO_COMPRESSION)
        complete_mipmap(path, channels, 4, 2)

    def parts(path, image):
        beauty = OpenEXR.Part({"type": OpenEXR.scanlineimage}, {c: np.ascontiguousarray(image[..., i])
                                                               for i, c in enumerate("RGB")}, "beauty")
        other = OpenEXR.Part({"type": OpenEXR.scanlineimage}, {c: np.ascontiguousarray(image[..., 2 - i])
                                                              for i, c in enumerate("RGB")}, "other")
        with OpenEXR.File([other, beauty]) as exr:
            exr.write(str(path))

    rewrite_frames(tmp_path / "tiled", tiled)
    rewrite_frames(tmp_path / "parts", parts)
    reference = stacks(tmp_path / "rgb")[1]
    np.testing.assert_array_equal(stacks(tmp_path / "tiled")[1], reference)
    with pytest.raises(DatasetError, match="2 parts hold channels R, G, B .'other', 'beauty'.; name one with 'part'"):
        open_dataset(tmp_path / "parts", radius=6, use_cache=False)
    edit_manifest(tmp_path / "parts", lambda m: m.update(part="beauty"))
    np.testing.assert_array_equal(stacks(tmp_path / "parts")[1], reference)


def test_xyz_frames_with_a_matrix_colorspace_give_correct_stacks_and_chromaticities(tmp_path, colour_impulses):
    """Frames in CIE XYZ (chromaticities R (1, 0), G (0, 1), B (0, 0), W (1/3, 1/3)) with
    ``colorspace`` the identity matrix: RGB is XYZ, so xy of a pixel is X / (X + Y + Z)."""
    xyz = (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1 / 3, 1 / 3)
    write_dataset(tmp_path / "rgb", HEIGHT, WIDTH, colour_impulses)
    write_dataset(tmp_path / "xyz", HEIGHT, WIDTH, colour_impulses)
    rewrite_frames(tmp_path / "xyz", lambda path, image: write_header(
        path, {c: image[..., i] for i, c in enumerate("RGB")}, chromaticities=xyz))
    with pytest.raises(DatasetError) as refused:
        open_dataset(tmp_path / "xyz", radius=6, use_cache=False)
    assert str(refused.value).startswith(f"{tmp_path / 'xyz' / 'frames' / '00000.exr'}: chromaticities "
                                         "R (1, 0) G (0, 1) B (0, 0) W (0.3333, 0.3333) differ from the "
                                         "dataset's colorspace sRGB (R (0.64, 0.33)")
    edit_manifest(tmp_path / "xyz", lambda m: m.update(colorspace={"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}))
    dataset, transients, _ = stacks(tmp_path / "xyz")
    np.testing.assert_array_equal(transients, stacks(tmp_path / "rgb")[1])
    pixel = np.array([0.2, 0.5, 0.3])
    np.testing.assert_allclose(chromaticity(pixel, dataset.colorspace), [0.2, 0.5], atol=1e-12)
    assert render(transients[1], (0.0, 1.0), DisplaySettings(), dataset.colorspace).shape == (HEIGHT, WIDTH, 3)


def test_aces_frames_with_a_primaries_colorspace_open_and_export(tmp_path, colour_impulses):
    write_dataset(tmp_path / "aces", HEIGHT, WIDTH, colour_impulses)
    rewrite_frames(tmp_path / "aces", lambda path, image: write_header(
        path, {c: image[..., i] for i, c in enumerate("RGB")}, chromaticities=ACES_AP0))
    primaries = {"primaries": [list(ACES_AP0[0:2]), list(ACES_AP0[2:4]), list(ACES_AP0[4:6])],
                 "whitepoint": list(ACES_AP0[6:8])}
    edit_manifest(tmp_path / "aces", lambda m: m.update(colorspace=primaries))
    dataset = open_dataset(tmp_path / "aces", radius=6, use_cache=False)
    # colour-science's own ACES2065-1 gives the same RGB -> XYZ matrix (published AP0 matrix).
    matrix = colour_module().RGB_COLOURSPACES[dataset.colorspace].matrix_RGB_to_XYZ
    np.testing.assert_allclose(matrix, colour_module().RGB_COLOURSPACES["ACES2065-1"].matrix_RGB_to_XYZ, atol=1e-6)
    assert main(["stack", str(tmp_path / "aces"), "--radii", "0:3:1", "--out", str(tmp_path / "out")]) == 0
    manifest, _ = read_stack(tmp_path / "out")
    assert manifest["colorspace"] == primaries


@pytest.mark.parametrize("bad, needle", [
    ({"matrix": [[1, 0, 0], [0, 1, 0]]}, "'colorspace.matrix' must be 3 x 3 finite numbers"),
    ({"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]}, "is not an RGB to XYZ matrix"),
    ({"primaries": [[0.6, 0.3], [0.3, 0.6]], "whitepoint": [0.3, 0.3]}, "'colorspace.primaries' must be 3 x 2"),
    ({"primaries": "sRGB"}, "must be a colourspace name"),
])
def test_a_bad_colorspace_is_one_line(tmp_path, colour_impulses, bad, needle):
    write_dataset(tmp_path / "ds", 2, 2, {q: colour_impulses[q][:2, :2] for q in [(0, 0), (1, 1)]})
    edit_manifest(tmp_path / "ds", lambda m: m.update(colorspace=bad))
    with pytest.raises(DatasetError) as refused:
        open_dataset(tmp_path / "ds", radius=2)
    assert "\n" not in str(refused.value) and "'colorspace'" in str(refused.value) and needle in str(refused.value)


def test_offset_windows_and_deep_frames_are_refused_with_one_line(tmp_path, colour_impulses, capfd):
    write_dataset(tmp_path / "ds", HEIGHT, WIDTH, colour_impulses)
    frame = tmp_path / "ds" / "frames" / "00003.exr"
    image = np.zeros((HEIGHT, WIDTH), np.float32)
    write_header(frame, {c: image for c in "RGB"}, dataWindow=((3, 2), (WIDTH + 2, HEIGHT + 1)),
                 displayWindow=((0, 0), (WIDTH - 1, HEIGHT - 1)))
    with pytest.raises(DatasetError) as refused:
        open_dataset(tmp_path / "ds", radius=6, use_cache=False)
    assert str(refused.value) == (f"{frame}: data window (3, 2)-({WIDTH + 2}, {HEIGHT + 1}) differs from display "
                                  f"window (0, 0)-({WIDTH - 1}, {HEIGHT - 1}); ringlight reads frames whose data "
                                  "window is their display window")
    write_deep(frame, HEIGHT, WIDTH)
    with pytest.raises(DatasetError) as refused:
        open_dataset(tmp_path / "ds", radius=6, use_cache=False)
    assert str(refused.value) == (f"{frame}: deep (per-sample) OpenEXR files are not supported; "
                                  "ringlight reads flat scanline or tiled images")
    assert capfd.readouterr() == ("", "")


def test_layer_recovery_says_colour_needs_an_rgb_camera(tmp_path, grey_impulses, capsys):
    write_dataset(tmp_path / "mono", HEIGHT, WIDTH, grey_impulses)
    rewrite_frames(tmp_path / "mono", lambda path, image: write_header(path, {"Y": image[..., 0]}))
    assert colour_unavailable(("R", "G", "B")) is None
    assert main(["layers", str(tmp_path / "mono"), "--radii", "1,2"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "monochrome (frames of one channel, Y): layer colours need an RGB camera" in error
    assert main(["info", str(tmp_path / "mono")]) == 0
    assert "channels     Y (monochrome: grey, layer colours need an RGB camera)" in capsys.readouterr().out


def test_the_layers_tab_says_a_monochrome_dataset_has_no_colours(qtbot, tmp_path, grey_impulses):
    from ringlight.app.window import MainWindow

    write_dataset(tmp_path / "mono", HEIGHT, WIDTH, grey_impulses)
    rewrite_frames(tmp_path / "mono", lambda path, image: write_header(path, {"Y": image[..., 0]}))
    window = MainWindow(plain_settings(tmp_path / "settings.ini"))
    qtbot.addWidget(window)
    try:
        with qtbot.waitSignal(window.dataset_loaded, timeout=60_000):
            window.open_dataset(tmp_path / "mono")
        window.show()
        window.analysis_tabs.setCurrentWidget(window.layer_panel)
        window.layer_tab.refresh()
        assert "layer colours need an RGB camera" in window.layer_panel.message_label.text()
        assert window.layer_tab.analysis is None
    finally:
        window.shutdown()
