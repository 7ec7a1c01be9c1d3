"""Every script in examples/ runs as it is, and what it prints or saves is right.

Each example runs as ``python examples/NAME.py ARGS`` runs it, as ``__main__`` with its own
arguments, folder and user cache, but in this process (as the documentation's gallery runs them):
a process of its own paid about 3 s of CPU again for the imports the suite has already made. Its
output is checked against the library called directly here (reading back files, opening
datasets) or brute force.
"""

import re
import runpy
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from reference import brute_ring_image
from ringlight.core import open_dataset, read_stack
from ringlight.core.colour.display import DisplaySettings, display_levels, render
from ringlight.core.colourspaces import colour_module
from ringlight.core.simulate.samples import ensure_demo_dataset

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def demo_cache(tmp_path_factory):
    """One demo dataset for the examples that open it (the bundled sample, written once)."""
    return tmp_path_factory.mktemp("examples-cache")


@pytest.fixture
def run_example(monkeypatch, capsys):
    """``run_example(NAME, *ARGS, cache=, cwd=)``: what ``python examples/NAME ARGS`` prints, run
    in ``cwd`` with the user cache ``cache``; an example that fails raises here."""
    def run(name: str, *args, cache: Path, cwd: Path) -> str:
        monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(cache))
        # Default output folders come from tempfile: keep them inside the test's own folder.
        monkeypatch.setattr(tempfile, "tempdir", str(cwd.parent))
        monkeypatch.setattr(sys, "argv", [str(EXAMPLES / name), *map(str, args)])
        monkeypatch.chdir(cwd)
        capsys.readouterr()
        runpy.run_path(str(EXAMPLES / name), run_name="__main__")
        assert not list(cwd.iterdir()), "examples never write into the current folder by surprise"
        return capsys.readouterr().out

    return run


def test_every_example_is_tested_and_short():
    scripts = sorted(path.name for path in EXAMPLES.glob("*.py"))
    tested = re.findall(r'run_example\("([a-z_]+\.py)"', Path(__file__).read_text())
    assert scripts == sorted(set(tested))
    for path in EXAMPLES.glob("*.py"):
        if path.name != "plugin_skeleton.py":
            assert len(path.read_text().splitlines()) < 40, path.name


def test_open_demo_example_saves_the_transient_png(demo_cache, tmp_path, monkeypatch, run_example):
    (tmp_path / "cwd").mkdir()
    out = run_example("open_demo_save_transient.py", tmp_path / "out", cache=demo_cache, cwd=tmp_path / "cwd")
    pixels = cv2.cvtColor(cv2.imread(str(tmp_path / "out" / "transient_r2.png")), cv2.COLOR_BGR2RGB)
    assert pixels.shape == (48, 48, 3) and "T_r at r = 2" in out
    # The PNG is T_2 = E_2 - E_3 brute-forced from the dataset's impulse images, drawn by the
    # display pipeline with its default settings (per-image 99.5th percentile).
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(demo_cache))
    dataset = open_dataset(ensure_demo_dataset())
    impulses = {(y, x): dataset.impulse_image(y, x) for y in range(48) for x in range(48)}
    transient = brute_ring_image(impulses, 48, 48, 2.0) - brute_ring_image(impulses, 48, 48, 3.0)
    settings = DisplaySettings()
    expected = render(transient, display_levels(transient, settings), settings, dataset.colorspace)
    assert np.abs(pixels.astype(int) - expected.astype(int)).max() <= 1


def test_export_stack_example_writes_the_stack_it_prints(demo_cache, tmp_path, run_example):
    (tmp_path / "cwd").mkdir()
    out = run_example("export_stack.py", cache=demo_cache, cwd=tmp_path / "cwd")
    folder = Path(re.search(r"wrote (\S+)", out).group(1))
    document, images = read_stack(folder)
    assert out.splitlines()[1] == "radii " + " ".join(f"{r:g}" for r in document["radii"]) == "radii 0 1 2 3 4 5 6"
    assert out.splitlines()[2] == "shape 7 48 48 3" and images.shape == (7, 48, 48, 3)


def test_simulate_example_writes_a_dataset_that_opens(tmp_path, run_example):
    (tmp_path / "cwd").mkdir()
    out = run_example("simulate_scene.py", tmp_path / "sim", cache=tmp_path / "cache", cwd=tmp_path / "cwd")
    dataset = open_dataset(tmp_path / "sim")
    assert f"grid 16 x 16, {len(dataset.manifest.frames)} frames" in out
    assert f"max_radius {dataset.max_radius:g}" in out
    printed = [line.split() for line in out.splitlines() if line.startswith("layer ")]
    for row, layer in zip(printed, dataset.manifest.ground_truth.layers, strict=True):
        assert row[1] == f"{layer.name}:" and row[3] == f"{layer.depth[0]:g}-{layer.depth[1]:g},"
        np.testing.assert_allclose(np.array(row[5:8], float), layer.rgb, atol=6e-5)


def test_layer_colour_example_prints_each_layer_beside_its_truth(tmp_path, run_example):
    (tmp_path / "cwd").mkdir()
    out = run_example("layer_colours.py", cache=tmp_path / "cache", cwd=tmp_path / "cwd")
    first, *lines = out.splitlines()
    dataset = open_dataset(first.removeprefix("dataset "))
    rows = [line.split() for line in lines]
    assert [row[3] for row in rows] == ["1", "3", "5"]
    # The truth is the xy of the manifest's layer RGB, converted here with colour-science directly.
    colour = colour_module()
    for row, layer in zip(rows, dataset.manifest.ground_truth.layers, strict=True):
        xy, truth_xy, error = np.array(row[5:7], float), np.array(row[10:12], float), float(row[13])
        assert row[8] == layer.name
        expected = colour.XYZ_to_xy(colour.RGB_to_XYZ(np.array(layer.rgb), dataset.colorspace))
        np.testing.assert_allclose(truth_xy, expected, atol=6e-5)
        assert abs(error - np.hypot(*(xy - truth_xy))) < 2e-4
        assert 0 < xy[0] < 0.8 and 0 < xy[1] < 0.9 and error < 0.3  # errors as measured: 0.087, 0.148, 0.119


def test_simulated_scan_example_captures_a_dataset_that_opens(tmp_path, run_example):
    (tmp_path / "cwd").mkdir()
    out = run_example("simulated_scan.py", tmp_path / "scan", cache=tmp_path / "cache", cwd=tmp_path / "cwd")
    dataset = open_dataset(tmp_path / "scan")
    # max_radius 3: a lattice of spacing floor(2 * 3) + 1 = 7 over 12 x 12 needs 7 x 7 frames
    assert len(dataset.manifest.frames) == 49 and dataset.grid_shape == (12, 12)
    assert f"49 frames for a 12 x 12 grid, {dataset.missing_count} points missing" in out


def test_plugin_skeleton_follows_the_protocols(tmp_path, run_example):
    (tmp_path / "cwd").mkdir()
    out = run_example("plugin_skeleton.py", cache=tmp_path / "cache", cwd=tmp_path / "cwd")
    assert out.splitlines() == ["camera follows the protocol: True", "projector follows the protocol: True"]


def test_the_gallerys_example_folders_are_fresh_and_removed(tmp_path, monkeypatch):
    """The documentation build's hooks (docs/_ext/ringlight_gallery.py): each example writes into a
    new empty folder under the system's temporary folder, its PNGs are what the scraper shows, and
    no folder outlives the build (one was left per example per build: 198 in /tmp here)."""
    monkeypatch.syspath_prepend(str(EXAMPLES.parent / "docs" / "_ext"))
    gallery = pytest.importorskip("ringlight_gallery")
    monkeypatch.setattr(gallery, "_BASE", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)
    folders = []
    for name in ("first", "second"):
        gallery.reset_example_folder({}, name)
        folder = Path(tempfile.gettempdir())
        assert folder.parent == tmp_path and not any(folder.iterdir())
        (folder / f"{name}.png").write_bytes(b"png")
        folders.append(folder)
        assert sorted(path.name for path in tmp_path.iterdir()) == [folder.name]  # the last one's removed
    gallery.remove_example_folders(None, None)  # the build's end
    assert not any(tmp_path.iterdir()) and tempfile.tempdir is None
