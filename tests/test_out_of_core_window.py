"""The explorer on a dataset read from its store: clicks read nothing, the impulse view reads in
a worker, and what it shows equals the in-memory path."""

import threading

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from reference import random_impulses, write_dataset
from ringlight.core import open_dataset
from ringlight.core.dataset import impulse_dataset, response_store
from ringlight.core.dataset.disc import disc_offset_count
from ringlight.core.rings.profiles import pixel_profile

TIMEOUT_MS = 120_000


@pytest.fixture
def folder(tmp_path, monkeypatch):
    impulses = random_impulses(np.random.default_rng(5), 20, 17, support=4)
    write_dataset(tmp_path / "ds", 20, 17, impulses, max_radius=4.0, multiplex=True)
    monkeypatch.setattr(response_store, "CHUNK_BYTES", 4 * 4 * disc_offset_count(4.0) * 12)
    return tmp_path / "ds"


def test_the_window_reads_an_out_of_core_dataset_without_io_on_clicks(qtbot, window, folder, monkeypatch):
    memory = open_dataset(folder, use_cache=False)
    monkeypatch.setattr(impulse_dataset, "memory_budget", lambda: 1)
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.open_dataset(str(folder))
    dataset = window.loaded.dataset
    assert not dataset.in_memory
    assert "out of core" in window.dataset_label.text()
    reads = []  # reads on the GUI thread (the noise estimate reads bands in its worker meanwhile)

    def watched(method):
        def read(*args):
            if threading.current_thread() is threading.main_thread():
                reads.append((method.__name__, args))
            return method(*args)
        return read

    monkeypatch.setattr(dataset.store, "window", watched(dataset.store.window))
    monkeypatch.setattr(dataset.store, "band", watched(dataset.store.band))
    window.pick(9, 8)
    assert not reads  # the profile comes from the stacks on screen
    expected = pixel_profile(memory, window.stacks.rings, (9, 8))
    assert_array_equal(window.profile.counts, expected.counts)
    assert_allclose(window.profile.transient, expected.transient, rtol=1e-6, atol=1e-7)
    assert_allclose(window.profile.outer_ring, expected.outer_ring, rtol=1e-6, atol=1e-7)
    monkeypatch.undo()
    window.display_controls.set_view("impulse")
    assert "reading the impulse image" in window.image_panel.title.textItem.toPlainText()
    qtbot.waitUntil(lambda: window._impulse_cache is not None, timeout=TIMEOUT_MS)
    assert_array_equal(window._impulse_cache[1], memory.impulse_image(9, 8))


def test_opening_out_of_core_previews_the_steady_state_band_by_band(qtbot, window, folder, monkeypatch):
    from ringlight.core.colour.display import UNDEFINED_RGB

    memory = open_dataset(folder, use_cache=False)
    monkeypatch.setattr(impulse_dataset, "memory_budget", lambda: 1)
    previews = []
    window.steady_previewed.connect(lambda steady, rows, colorspace: previews.append((steady, rows)))
    said = []  # a click on the preview, while it opens: told why nothing happens
    window.steady_previewed.connect(lambda *_: (window.pick(1, 1), said.append(window.statusBar().currentMessage())))
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(str(folder))
    assert said[0] == "Still opening: points can be picked once the stacks are ready"
    # Five 4-row bands as the store is built, then the whole steady state before the stacks.
    assert [rows for _, rows in previews] == [4, 8, 12, 16, 20, 20]
    for steady, rows in previews:
        assert_array_equal(steady[:rows], memory.steady_state()[:rows])
        assert np.isnan(steady[rows:]).all()
    # Drawn while nothing else is on screen: built rows in colour, the rest undefined grey.
    window.loaded = None
    window.show_steady_preview(previews[1][0], 8, "sRGB")
    pixels = window.image_panel.pixels()
    assert (pixels[8:] == UNDEFINED_RGB).all() and not (pixels[:8] == UNDEFINED_RGB).all()
    assert "rows 0..8 of 20" in window.image_panel.title.textItem.toPlainText()
    window._hint_when_empty()  # the open failed or was cancelled: the preview goes
    assert window.image_panel.pixels() is None


def test_the_display_kernels_are_loaded_before_the_first_image_is_drawn(qtbot, window, folder, monkeypatch):
    """The window's start-up warm-up covers the kernels' types of every image drawn here (steady
    state, stacks, an impulse image read from the store), so that none compiles on the GUI thread."""
    from ringlight.core.colour import display
    display.warm_up_display()
    kernels = (display._colour_pass, display._finite_and_negative)
    warmed = [set(kernel.signatures) for kernel in kernels]
    monkeypatch.setattr(impulse_dataset, "memory_budget", lambda: 1)
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.open_dataset(str(folder))
    for view in ("steady", "ring", "transient", "impulse"):
        window.display_controls.set_view(view)
    qtbot.waitUntil(lambda: window._impulse_cache is not None, timeout=TIMEOUT_MS)
    window.display_controls.set_view("steady")
    window.display_controls.set_view("impulse")  # drawn from the cache now
    assert [set(kernel.signatures) for kernel in kernels] == warmed


def test_dataset_information_says_how_big_it_is_where_its_store_is_and_how_it_is_open(qtbot, window, folder,
                                                                                       monkeypatch):
    from ringlight.core.dataset.memory import format_bytes

    monkeypatch.setattr(impulse_dataset, "memory_budget", lambda: 1)
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.open_dataset(str(folder))
    lines = {line[:12].strip(): line[13:] for line in window.dataset_information().splitlines()}
    responses = 20 * 17 * disc_offset_count(4.0) * 3 * 4  # grid points x offsets x channels x float32
    assert lines["grid"] == "20 x 17"
    assert lines["responses"].startswith(f"{format_bytes(responses)} at radius 4 ")
    stored = sum(path.stat().st_size for path in (folder / ".ringlight-cache").rglob("*") if path.is_file())
    assert lines["store"] == f"{format_bytes(stored)} on disk in {(folder / '.ringlight-cache').resolve()}"
    assert lines["opened"] == "out of core: read from its store band by band"
