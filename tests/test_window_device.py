"""Settings > Device: the window's device setting, persisted, and handed by its workers to the
core calls that take ``device=`` (the stacks' ring sums, the inverse fit's white runs, the optics
table's white run)."""

import numpy as np
import pytest
from plain_view import plain_settings
from reference import random_impulses, write_dataset
from optics_helpers import TEST_PHOTONS
from ringlight.app import optics_view, window_device
from ringlight.app.window import MainWindow
from ringlight.core.device import Device, cuda_device
from ringlight.core.rings import stack_request

TIMEOUT_MS = 120_000
FAKE_GPU = Device("cuda", "Fake GPU 80GB")


def make_window(qtbot, path):
    window = MainWindow(plain_settings(path))
    qtbot.addWidget(window)
    return window


@pytest.mark.skipif(cuda_device() is not None, reason="a GPU is usable here")
def test_without_a_gpu_the_menu_offers_the_cpu_only_and_says_why(qtbot, tmp_path):
    window = make_window(qtbot, tmp_path / "settings.ini")
    actions = window.device_actions
    assert not actions["cuda"].isEnabled() and actions["cpu"].isEnabled() and actions["auto"].isEnabled()
    assert actions["cuda"].statusTip() == window_device.NO_GPU
    assert "no usable GPU" in actions["auto"].text()
    texts = [action.text() for action in actions["cuda"].parent().findChildren(type(actions["cuda"]))]
    assert window_device.NO_GPU in texts
    assert window.device_choice() == "auto" and window.compute_device().kind == "cpu"
    # A saved "cuda" (from a machine that had one) falls back to auto, which runs on the CPU here.
    window.set_device_choice("cuda")
    assert window.device_choice() == "auto" and window.layer_tab.device == "cpu"
    window.shutdown()


def test_the_device_choice_is_kept_between_runs(qtbot, tmp_path):
    first = make_window(qtbot, tmp_path / "settings.ini")
    first.device_actions["cpu"].trigger()
    assert first.device_choice() == "cpu"
    first.save_settings()
    first.shutdown()
    second = make_window(qtbot, tmp_path / "settings.ini")
    assert second.device_choice() == "cpu" and second.layer_tab.device == "cpu"
    second.shutdown()


def test_with_a_gpu_the_stack_worker_sums_the_rings_on_it(qtbot, tmp_path, monkeypatch):
    # A usable GPU as numba would report it: the menu names it, and the stack worker hands it to
    # ring_and_transient_stacks (recorded here, then summed on the CPU: no GPU on CI). The stacks
    # shown are the CPU's, to the last bit.
    monkeypatch.setattr(window_device, "cuda_device", lambda: FAKE_GPU)
    monkeypatch.setattr(window_device, "choose_device",
                        lambda choice: FAKE_GPU if choice in ("auto", "cuda") else Device("cpu", "CPU (2 cores)"))
    seen = []
    original = stack_request.ring_and_transient_stacks

    def recording(*arguments, device=None, **keywords):
        seen.append(device)
        return original(*arguments, **keywords)

    monkeypatch.setattr(stack_request, "ring_and_transient_stacks", recording)
    window = make_window(qtbot, tmp_path / "settings.ini")
    assert window.device_actions["cuda"].isEnabled() and "Fake GPU 80GB" in window.device_actions["cuda"].text()
    window.device_actions["cuda"].trigger()
    assert window.layer_tab.device == "cuda"
    impulses = random_impulses(np.random.default_rng(3), 8, 8, support=3)
    write_dataset(tmp_path / "ds", 8, 8, impulses, max_radius=3)
    with qtbot.waitSignal(window.stacks_ready, timeout=TIMEOUT_MS):
        window.open_dataset(tmp_path / "ds")
    assert seen and seen[-1] == FAKE_GPU
    from ringlight.core import open_dataset
    from ringlight.core.rings.stacks import ring_and_transient_stacks

    pair = window.stacks.pair
    _, transient = ring_and_transient_stacks(open_dataset(tmp_path / "ds"), pair.radii, pair.request.dr,
                                             pair.request.thickness)
    assert np.array_equal(pair.transient.images, transient.images, equal_nan=True)
    window.shutdown()


def test_with_a_gpu_the_optics_tab_traces_its_table_on_it(qtbot, tmp_path, monkeypatch):
    # The Optics tab's worker traces the table's white run on the chosen GPU (recorded here, then
    # traced on the CPU: no GPU on CI) for the manifest's n and the default g, before the fits,
    # which then read it from the user cache: the maps are core's, to the last bit. (The dataset
    # opens on the CPU, so that its stacks need no GPU.)
    monkeypatch.setattr(window_device, "cuda_device", lambda: FAKE_GPU)
    seen = []
    original = optics_view.radial_run

    def recording(n, g, photons, *arguments, device=None, **keywords):
        seen.append((n, g, photons, device))
        return original(n, g, photons, *arguments, **keywords)

    monkeypatch.setattr(optics_view, "radial_run", recording)
    window = make_window(qtbot, tmp_path / "settings.ini")
    window.device_actions["cpu"].trigger()
    window.optics_photons = TEST_PHOTONS
    impulses = random_impulses(np.random.default_rng(5), 8, 8, support=3)
    write_dataset(tmp_path / "ds", 8, 8, impulses, max_radius=3, extra={"sample": {"n": 1.33}})
    with qtbot.waitSignal(window.dataset_loaded, timeout=TIMEOUT_MS):
        window.open_dataset(tmp_path / "ds")
    qtbot.waitUntil(lambda: not window.stack_jobs.busy, timeout=TIMEOUT_MS)
    monkeypatch.setattr(window_device, "choose_device", lambda choice: FAKE_GPU)
    window.device_actions["cuda"].trigger()
    window.optics_panel.compute_button.click()
    qtbot.waitUntil(lambda: window.optics is not None, timeout=TIMEOUT_MS)
    assert seen == [(1.33, 0.0, TEST_PHOTONS, FAKE_GPU)]
    from ringlight.core import open_dataset
    from ringlight.core.optics import optical_maps

    direct = optical_maps(open_dataset(tmp_path / "ds"), photons=TEST_PHOTONS)
    assert np.array_equal(window.optics.mua, direct.mua, equal_nan=True)
    assert np.array_equal(window.optics.musp_se, direct.musp_se, equal_nan=True)
    window.shutdown()
