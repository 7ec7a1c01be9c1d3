"""Capture: plugins, simulated rig, Gray code correspondence, HDR merge, scans that stop and resume,
and the CLI producing a dataset whose transients match the simulated scene's own."""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from reference import write_dataset
from ringlight.app.main import main
from ringlight.core import Cancelled, RinglightError, open_dataset, transient_stack
from ringlight.core.capture.hardware import HardwareError, discover_plugins, make_device
from ringlight.core.capture.hdr import bracket_exposures, merge_brackets
from ringlight.core.capture.scan import Scan
from ringlight.core.capture.scan_plan import ScanError, ScanPaused, ScanPlan
from ringlight.core.capture.simulated_presets import preset_rig
from ringlight.core.capture.simulated_rig import CameraSampling, SimulatedRig
from ringlight.core.capture.workflow import measure_correspondence

SIZE, RADIUS = 16, 5


def analytic_windows(size=SIZE, radius=RADIUS):
    """Impulse responses exp(-d / 1.5) within ``radius``, brighter along a vertical sine."""
    distance = np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1])
    kernel = (np.exp(-distance / 1.5) * (distance <= radius))[..., None] * [0.2, 0.15, 0.1]
    rows = np.arange(size)[:, None, None, None, None]
    return (kernel[None, None] * (1 + 0.5 * np.sin(rows / 3.0))).repeat(size, axis=1).astype(np.float32)


def scan_plan():
    return ScanPlan((2, 2, 14, 14), 3.0, (0.002, 0.008), noise_floor=6.0)


def identity_mapping(rig, roi):
    """The rig's true camera -> grid mapping (what a perfect correspondence gives)."""
    rows, cols = np.mgrid[:rig.seen_y.shape[0], :rig.seen_y.shape[1]]
    y, x = rig.sampling.projector_position(rows, cols)
    mapping = np.full((*rows.shape, 2), np.nan, np.float32)
    inside = (np.floor(y) >= roi[0]) & (np.floor(y) < roi[2]) & (np.floor(x) >= roi[1]) & (np.floor(x) < roi[3])
    mapping[inside, 0] = (y - roi[0] - 0.5)[inside]
    mapping[inside, 1] = (x - roi[1] - 0.5)[inside]
    return mapping


@pytest.mark.parametrize("sampling", [CameraSampling(), CameraSampling(scale=1.5, rotation_deg=-3.0, offset=(0.3, -1.2))])
def test_gray_code_recovers_the_camera_sampling_to_sub_pixel_accuracy(sampling):
    rig = SimulatedRig(analytic_windows(24, 6), sampling=sampling)
    correspondence = measure_correspondence(rig.camera, rig.projector)
    rows, cols = np.nonzero(rig.sees_scene)
    true_y, true_x = sampling.projector_position(rows, cols)
    fitted_y, fitted_x = correspondence.projector_position(rows, cols)
    error = np.hypot(fitted_y - true_y, fitted_x - true_x)
    # Measured: max 0.28 px, rms 0.12 px (default sampling); max 0.26 px, rms 0.09 px (the second).
    assert error.max() < 0.35 and np.sqrt((error ** 2).mean()) < 0.15
    assert correspondence.inliers > 0.9 * rig.sees_scene.sum()


def test_hdr_merge_is_exact_without_noise_and_flags_pixels_saturated_everywhere():
    rate = np.array([[10.0, 1000.0], [1e5, 1e7]])  # counts per second above black
    exposures = bracket_exposures(1e-3, 0.1, 10.0)
    assert exposures == pytest.approx([1e-3, 1e-2, 0.1])
    frames = [np.minimum(rate * t + 64, 4095) for t in exposures]
    merged = merge_brackets(frames, exposures, black_level=64, saturation_level=4095, noise_floor=0.0)
    # 1e7/s saturates even at 1 ms: flagged, radiance the lower bound (4095 - 64) / 1e-3.
    assert merged.saturated.tolist() == [[False, False], [False, True]]
    np.testing.assert_allclose(merged.radiance[~merged.saturated], rate[~merged.saturated], rtol=1e-6)
    assert merged.radiance[1, 1] == pytest.approx(4031 / 1e-3)
    with pytest.raises(RinglightError, match="one exposure per frame"):
        merge_brackets(frames[:2], exposures, 64, 4095)


def test_pixels_saturated_in_every_bracket_are_mapped_per_camera_pixel(tmp_path):
    from ringlight.core.dataset.exr import read_exr_rgb

    rig = SimulatedRig(analytic_windows())
    plan = ScanPlan((2, 2, 14, 14), 3.0, (0.05,))  # one long exposure: every lit point saturates
    out = run_scan(tmp_path / "scan", rig, plan)
    saturation = read_exr_rgb(out / ".scan/saturation.exr")[..., 0]
    journal = [json.loads(line) for line in (out / ".scan/journal.jsonl").read_text().splitlines()]
    assert sum(entry["saturated"] for entry in journal) > 0
    # Each frame's count is of (pixel, channel) pairs; the map counts pixels with any channel.
    assert 0 < saturation.sum() <= sum(entry["saturated"] for entry in journal)
    lit_pixels = rig.sees_scene.sum()
    assert saturation.max() <= len(journal) and (saturation > 0).sum() <= lit_pixels
    assert "saturated in every bracket (per camera pixel: .scan/saturation.exr)" in json.loads(
        (out / "dataset.json").read_text())["notes"]


def run_scan(out, rig, plan=None, **kwargs):
    plan = plan or scan_plan()
    scan = Scan(out, plan, identity_mapping(rig, plan.roi))
    scan.prepare(resume=kwargs.pop("resume", False))
    return scan.run(rig.camera, rig.projector, **kwargs)


def frame_files(folder):
    return {path.relative_to(folder).as_posix(): path.read_bytes()
            for path in sorted(Path(folder).rglob("*.exr"))}


def test_a_scan_stopped_midway_and_resumed_equals_an_uninterrupted_one(tmp_path):
    windows = analytic_windows()
    whole = run_scan(tmp_path / "whole", SimulatedRig(windows))
    rig = SimulatedRig(windows)
    stop_after = iter(range(100))
    with pytest.raises(Cancelled, match="resume to continue"):
        run_scan(tmp_path / "part", rig, should_stop=lambda: next(stop_after) >= 7)
    assert not (tmp_path / "part/dataset.json").exists()
    with open(tmp_path / "part/.scan/journal.jsonl", "a") as journal:
        journal.write('{"index": 8, "fi')  # a line torn by a power cut
    with pytest.raises(ScanError, match="unfinished scan"):
        run_scan(tmp_path / "part", SimulatedRig(windows))
    resumed = run_scan(tmp_path / "part", SimulatedRig(windows), resume=True)
    assert frame_files(resumed) == frame_files(whole)
    assert json.loads((resumed / "dataset.json").read_text()) == json.loads((whole / "dataset.json").read_text())


def test_a_camera_that_stops_answering_pauses_the_scan(tmp_path):
    windows = analytic_windows()
    with pytest.raises(ScanPaused, match="paused after 3 of 49 frames: simulated camera stopped answering"):
        # dark + 3 frames, 2 brackets each, and the projector check before frame 0 (one capture)
        run_scan(tmp_path / "scan", SimulatedRig(windows, fail_after=9))

    class HangingCamera:
        def __init__(self, camera):
            self.camera = camera

        def __getattr__(self, name):
            return getattr(self.camera, name)

        def capture(self, exposure):
            time.sleep(3)

    rig = SimulatedRig(windows)
    scan = Scan(tmp_path / "scan", scan_plan(), identity_mapping(rig, scan_plan().roi))
    scan.prepare(resume=True)
    with pytest.raises(ScanPaused, match="did not answer within"):
        scan.run(HangingCamera(rig.camera), rig.projector, timeout=0.2)
    assert len(scan.finished_frames()) == 3
    assert run_scan(tmp_path / "scan", SimulatedRig(windows), resume=True) == tmp_path / "scan"


def test_a_full_disk_pauses_the_scan_before_writing(tmp_path, monkeypatch):
    import shutil

    from ringlight.core.capture import scan as scan_module

    real = shutil.disk_usage
    monkeypatch.setattr(scan_module.shutil, "disk_usage", lambda path: real(path)._replace(free=1000))
    rig = SimulatedRig(analytic_windows())
    frame_bytes = rig.seen_y.size * 12  # float32 RGB per camera pixel
    assert frame_bytes == 15552
    with pytest.raises(ScanPaused, match=r"only 1000 B free, a frame needs 15.2 KiB; free some space"):
        run_scan(tmp_path / "scan", rig)
    assert not list((tmp_path / "scan/frames").iterdir())


def test_a_plugin_that_fails_to_import_is_skipped_with_a_message(tmp_path, monkeypatch):
    import importlib

    (tmp_path / "broken_rig.py").write_text("raise RuntimeError('driver library missing')\n")
    info = tmp_path / "broken_rig-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-rig\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[ringlight.hardware]\nbroken = broken_rig:PLUGIN\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    discovery = discover_plugins()
    assert ("broken", "failed to load broken_rig:PLUGIN: RuntimeError: driver library missing") in discovery.failures
    assert "simulated" in discovery.cameras() and "simulated" in discovery.projectors()
    sys.modules.pop("broken_rig", None)


def test_a_plugin_that_did_not_load_is_told_in_the_list_and_when_a_device_asked_for_is_missing(tmp_path, capsys,
                                                                                             monkeypatch):
    """Every capture began with a warning per plugin that did not load (FLIR's SDK absent, with the
    simulated rig asked for). It is told by ``--list``, and in the one line that says the device asked
    for is not there; a capture of a device that is there says nothing of it."""
    from dataclasses import replace

    from ringlight.app.cli import capture

    broken = replace(discover_plugins(), failures=(("broken", "driver library missing"),))
    monkeypatch.setattr(capture, "discover_plugins", lambda: broken)
    assert main(["capture", "--list"]) == 0
    assert capsys.readouterr().err == "warning: hardware plugin broken skipped: driver library missing\n"
    assert main(["capture", "--camera", "broken-camera", "--projector", "simulated", "--out", str(tmp_path / "a")]) == 2
    cameras = ", ".join(sorted(broken.cameras()))
    assert capsys.readouterr().err == (f"ringlight: error: --camera 'broken-camera': no such device (available: "
                                       f"{cameras}); hardware plugin broken skipped: driver library missing\n")
    assert main(["capture", "--camera", "simulated", "--projector", "simulated", "--out", str(tmp_path / "b"),
                 "--max-radius", "0"]) == 2  # refused before any device opens: nothing else to say
    assert capsys.readouterr().err.splitlines() == [
        "ringlight: error: --max-radius must be > 0 and at most 4096 grid steps, got 0"]


def grid_dataset_from_windows(folder, windows, max_radius):
    """The scene's own impulse dataset: each lit point's window placed in a grid frame."""
    height, width = windows.shape[:2]
    radius = (windows.shape[2] - 1) // 2
    impulses = {}
    for qy in range(height):
        for qx in range(width):
            image = np.zeros((height, width, 3), np.float32)
            for dy in range(-radius, radius + 1):
                for dx in range(-radius, radius + 1):
                    if 0 <= qy + dy < height and 0 <= qx + dx < width and np.hypot(dy, dx) <= max_radius:
                        image[qy + dy, qx + dx] = windows[qy, qx, dy + radius, dx + radius]
            impulses[(qy, qx)] = image
    write_dataset(folder, height, width, impulses, max_radius=max_radius, multiplex=True)


def test_capture_command_makes_a_dataset_whose_transients_match_the_scene(tmp_path, capsys):
    options = ["--option", "size=12x12", "--option", "photons=400"]
    assert main(["capture", "--camera", "simulated", "--projector", "simulated", *options,
                 "--max-radius", "4", "--out", str(tmp_path / "captured")]) == 0
    printed = capsys.readouterr().out
    assert "81 frames instead of 144" in printed and "open it with: ringlight" in printed
    rig = preset_rig(size="12x12", photons="400")
    grid_dataset_from_windows(tmp_path / "scene", rig.windows, 4.0)
    radii = [0.0, 1.0, 2.0]
    captured = transient_stack(open_dataset(tmp_path / "captured", use_cache=False), radii, step=1.0)
    scene = transient_stack(open_dataset(tmp_path / "scene", use_cache=False), radii, step=1.0)
    for index in range(len(radii)):
        truth = scene.images[index]
        error = np.abs(captured.images[index] / rig.sensor.gain - truth)
        # Measured: mean |error| / mean |T| = 2.0 %, 1.6 %, 4.6 % at r = 0, 1, 2 (shot and read noise
        # of the bracket, about 4 camera pixels per grid point, mapping edges).
        assert np.nanmean(error) / np.nanmean(np.abs(truth)) < [0.03, 0.03, 0.07][index]


SMALL_CAPTURE = ["capture", "--camera", "simulated", "--projector", "simulated", "--option", "size=10x10",
                 "--option", "photons=200", "--max-radius", "3"]
"""The command line of a small simulated scan, less its ``--out``."""


@pytest.fixture(scope="module")
def uninterrupted_capture(tmp_path_factory):
    """The folder of :data:`SMALL_CAPTURE` run through once, without a stop: the dataset that
    every stopped and resumed scan of it must equal (made once for the module; not to be written)."""
    folder = tmp_path_factory.mktemp("uninterrupted") / "whole"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RINGLIGHT_CACHE_DIR", str(folder.parent / "cache"))
        assert main([*SMALL_CAPTURE, "--out", str(folder)]) == 0
    return folder


def test_capture_command_pauses_on_a_failing_camera_and_resumes(tmp_path, capsys, uninterrupted_capture):
    base = [*SMALL_CAPTURE, "--out", str(tmp_path / "scan")]
    assert main([*base, "--camera-option", "fail_after=60"]) == 2  # the camera's own option: one rig still
    assert "scan paused after" in capsys.readouterr().err
    paused = frame_files(tmp_path / "scan")
    # A resume on another rig wrote frames of two scenes into one dataset: refused, nothing written.
    assert main([*base, "--option", "seed=5", "--resume"]) == 2
    error = capsys.readouterr().err.splitlines()
    began = f"ringlight: error: {tmp_path / 'scan'}: the scan began with another camera or other settings"
    assert len(error) == 1 and error[0].startswith(f"{began} (camera: backend simulated, bits 12, ")
    assert error[0].endswith("rig scene red-bead; size 10x10; photons 200; seed 5: resume with those")
    assert frame_files(tmp_path / "scan") == paused
    assert main([*base, "--resume"]) == 0
    assert frame_files(tmp_path / "scan") == frame_files(uninterrupted_capture)
    assert main([*SMALL_CAPTURE, "--out", str(uninterrupted_capture)]) == 2  # never overwrites a dataset
    assert "already holds a finished dataset" in capsys.readouterr().err


@pytest.mark.parametrize("under, expected", [
    ("", "{file}: exists and is not a folder; refusing to write a scan into it"),
    ("x", "{file}/x: {file} is a file, not a folder; give another path"),
])
def test_an_output_that_is_or_lies_under_a_file_is_refused_before_any_device_is_made(tmp_path, capsys, monkeypatch,
                                                                                     under, expected):
    """A user's walkthrough: ``--out afile`` (a regular file) ran the correspondence and the plan
    before "afile: exists and is not a folder", and ``--out afile/x`` failed after them with
    "cannot write here: File exists", which did not say that afile is a file. Both are refused
    before a device is made (with a real rig: before anything is projected); nothing is written."""
    from ringlight.app.cli import capture

    def no_device(*args, **kwargs):
        raise AssertionError("a device was made before the output was checked")

    monkeypatch.setattr(capture, "make_device", no_device)
    afile = tmp_path / "afile"
    afile.write_text("mine")
    assert main([*SMALL_CAPTURE, "--out", str(afile / under)]) == 2
    assert capsys.readouterr().err.splitlines() == ["ringlight: error: " + expected.format(file=afile)]
    assert afile.read_text() == "mine" and list(tmp_path.iterdir()) == [afile]


GIVE_ONCE = "give scene, size, photons and seed once, as options for both devices"


@pytest.mark.parametrize("options, problem", [
    (["--camera-option", "seed=1"],
     f"the camera and the projector were given different simulated rigs (seed: camera 1, projector 0): {GIVE_ONCE}"),
    (["--projector-option", "size=12x10", "--projector-option", "seed=2"],
     "the camera and the projector were given different simulated rigs (seed: camera 0, projector 2; size: camera "
     f"10x10, projector 12x10): {GIVE_ONCE}"),
    (["--projector-option", "fail_after=3"],
     "fail_after=3 was given to the projector alone: it is the simulated camera's option; give it to the camera, "
     "or as an option for both devices"),
])
def test_a_camera_and_projector_given_different_rigs_are_refused_before_anything_is_simulated(
        tmp_path, capsys, monkeypatch, options, problem):
    """A user's walkthrough: ``--camera-option seed=1`` made the camera a rig of its own, which
    never saw the projector's patterns: the Gray code correspondence failed as junk after both
    rigs were simulated. The pair is refused in one line naming what differs, before the
    simulator runs; nothing is written. So is ``fail_after`` given to the projector alone, where
    the scan ran whole and rehearsed no failure."""
    from ringlight.core.simulate import transport

    def no_simulation(*args, **kwargs):
        raise AssertionError("a rig was simulated before the pair was checked")

    monkeypatch.setattr(transport, "simulate_transport", no_simulation)
    assert main([*SMALL_CAPTURE, *options, "--out", str(tmp_path / "scan")]) == 2
    assert capsys.readouterr().err.splitlines() == [f"ringlight: error: {problem}"]
    assert list(tmp_path.iterdir()) == []


def test_a_simulated_device_with_a_real_one_is_refused_and_the_same_options_make_one_rig():
    """``pair_problem``: a simulated camera films only its rig's projector, a simulated projector
    lights only its rig's scene; devices without a rig are not checked. The camera's own
    ``fail_after`` (given to the projector too, as ``--option`` does) leaves the two one rig."""
    from ringlight.core.capture.hardware import pair_problem
    from ringlight.core.capture.simulated_presets import simulated_camera, simulated_projector

    camera = simulated_camera(size="4x4", photons="10", fail_after="3")
    projector = simulated_projector(size="4x4", photons="10", fail_after="3")
    assert pair_problem(camera, projector) is None and camera.rig is projector.rig
    real = object()
    assert pair_problem(real, projector) == ("the simulated projector lights only its simulated scene, which a real "
                                             "camera does not see: use a simulated camera with it")
    assert pair_problem(camera, real) == ("the simulated camera sees only the simulated projector's scene: use the "
                                          "simulated projector with it")
    assert pair_problem(real, object()) is None
    # fail_after counts this camera's captures only: a camera made afresh over the same rig starts at 0.
    projector.show_white()
    for _ in range(3):
        camera.capture(0.01)
    with pytest.raises(HardwareError, match="fail_after reached"):
        camera.capture(0.01)
    assert simulated_camera(size="4x4", photons="10").capture(0.01).shape == camera.frame_shape


SIZE_RANGE = "must be HxW projector pixels, at least 2x2 and at most 1024x1024, e.g. 24x24"


@pytest.mark.parametrize("flag, option, problem", [
    ("--option", "photons=0", "must be an integer from 1 to 10,000,000"),
    ("--camera-option", "photons=-5", "must be an integer from 1 to 10,000,000"),
    ("--option", "seed=-1", "must be an integer from 0 to 4,294,967,295"),
    ("--option", "fail_after=x", "must be an integer 0 or more"),
    ("--option", "size=0x0", SIZE_RANGE),
    ("--option", "size=1x8", SIZE_RANGE),  # OpenCV's Gray code decoding crashed the process (SIGSEGV)
    ("--option", "size=400x400", "preset red-bead: simulating it would take 21 GiB (grid 400 x 400, max_radius 12, "
                                 "path_length_bins.count 64), more than 16 GiB; make the grid, max_radius or "
                                 "path_length_bins.count smaller"),
    ("--option", "foo=1", "no such option of the simulated rig (its options: scene, size, photons, seed, fail_after)"),
    ("--option", "scene=nope", "must be colorchecker, a simulator preset (homogeneous, layers-mus, layers-reversed, "
                               "layers-thick, layers2, layers3, marble, red-bead, skin1, star, wholemilk) or a scene "
                               "JSON file"),
])
def test_a_simulated_rig_option_out_of_range_is_one_line_naming_it_before_anything_is_simulated(
        tmp_path, capsys, monkeypatch, flag, option, problem):
    """A user's walkthrough: ``--camera-option photons=-5`` and ``--option photons=0`` wrote a
    dataset (0 photons fell back to the preset's 20000); ``--option size=0x0`` said "'shapes[0]'
    centre [0, 0, 7] is outside the volume", which named no option. Each option is checked
    against its range, before the simulator runs, and named as the user gave it."""
    from ringlight.core.simulate import transport

    def no_simulation(*args, **kwargs):
        raise AssertionError("the scene was simulated before the option was checked")

    monkeypatch.setattr(transport, "simulate_transport", no_simulation)
    assert main([*SMALL_CAPTURE, flag, option, "--out", str(tmp_path / "scan")]) == 2
    assert capsys.readouterr().err.splitlines() == [f"ringlight: error: {flag} {option}: {problem}"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["nan", "inf", "0", "-5", "3601", "abc"])
def test_a_machine_vision_cameras_frame_timeout_must_be_a_positive_number_of_seconds(value):
    """``frame_timeout=nan`` (or inf) was taken, and failed at the first capture, after the
    projector had begun; 0 or less never sees a frame."""
    from ringlight.core.capture.hardware import OptionError
    from ringlight.core.capture.pylon_camera import PylonCamera

    with pytest.raises(OptionError) as refused:
        PylonCamera("0815-0000", frame_timeout=value)
    assert str(refused.value) == (f"pylon camera 0815-0000 option frame_timeout={value}: "
                                  "must be a number of seconds > 0 and at most 3600")


def test_opening_a_simulated_rig_reports_its_progress_and_a_reopen_is_instant():
    """The simulated rig's making is most of an open (the simulator runs): its factory gets the
    progress callback, which the rig's making reports to when the device opens (the factory itself
    only checks the options); factories that do not name one never see it."""
    cameras, projectors = discover_plugins().cameras(), discover_plugins().projectors()
    fractions = []
    options = {"size": "6x5", "photons": "40", "seed": "11"}
    camera = make_device(cameras, "simulated", options, fractions.append)
    assert fractions == [] and camera.simulated_scene == {"scene": "red-bead", "size": "6x5", "photons": "40",
                                                          "seed": "11"}
    camera.open()
    assert fractions and fractions[-1] == pytest.approx(1.0) and fractions == sorted(fractions)
    again = []
    projector = make_device(projectors, "simulated", {**options, "seed": "011"}, again.append)
    projector.open()
    assert projector.rig is camera.rig and again == []
    seen = {}
    plain = make_device({"plain": lambda **kwargs: seen.update(kwargs) or "device"}, "plain", {"a": "1"},
                        fractions.append)
    assert plain == "device" and seen == {"a": "1"}


def test_opencv_camera_without_a_device_says_so():
    from ringlight.core.capture.opencv_camera import OpenCVCamera

    with pytest.raises(HardwareError, match="no camera at index 97"):
        OpenCVCamera("97").open()
    with pytest.raises(HardwareError, match="index must be an integer"):
        OpenCVCamera("usb")


def test_screen_projector_draws_patterns_in_physical_pixels(qtbot):
    from PySide6.QtGui import QGuiApplication
    from ringlight.widgets.screen_projector import ScreenProjector

    projector = ScreenProjector(screen="0", settle="0")
    projector.open()
    try:
        screen = QGuiApplication.screens()[0]
        ratio = screen.devicePixelRatio()
        assert projector.size == (round(screen.geometry().height() * ratio), round(screen.geometry().width() * ratio))
        pattern = np.zeros(projector.size, np.float32)
        pattern[10:20, 30:35] = 1.0
        projector.show(pattern)
        image = projector.window.image
        assert (image.width(), image.height()) == (projector.size[1], projector.size[0])
        pixels = np.array([[image.pixelColor(x, y).red() for x in range(40)] for y in range(25)])
        assert np.array_equal(pixels > 127, pattern[:25, :40] > 0.5)
        with pytest.raises(HardwareError, match="is not the screen's"):
            projector.show(np.zeros((3, 3)))
    finally:
        projector.close()
    with pytest.raises(HardwareError, match="no screen 9"):
        ScreenProjector(screen="9").open()


def test_a_capture_process_killed_mid_scan_resumes_to_the_same_dataset(tmp_path, uninterrupted_capture):
    """The process killed must be a process of its own; the resume, as a user's next command, reads
    everything from the folder, so it runs here."""
    import subprocess

    process = subprocess.Popen([sys.executable, "-m", "ringlight.app.main", *SMALL_CAPTURE, "--out",
                                str(tmp_path / "killed")], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    frames = tmp_path / "killed/frames"
    for _ in range(12_000):  # a bounded wait (polls, not the clock) for five frames on disk
        if frames.exists() and len(list(frames.glob("*.exr"))) >= 5:
            break
        time.sleep(0.01)
    process.kill()  # SIGKILL: no clean-up runs
    process.wait()
    assert not (tmp_path / "killed/dataset.json").exists()
    assert main([*SMALL_CAPTURE, "--out", str(tmp_path / "killed"), "--resume"]) == 0
    assert frame_files(tmp_path / "killed") == frame_files(uninterrupted_capture)
    assert not list((tmp_path / "killed").rglob("*partial*"))


def test_byte_counts_are_shown_in_units_that_keep_their_digits():
    from ringlight.core.dataset.memory import format_bytes

    assert [format_bytes(n) for n in (0, 1000, 15552, 3 * 2**20 + 2**19, 5 * 2**30, 2**50)] == [
        "0 B", "1000 B", "15.2 KiB", "3.5 MiB", "5.0 GiB", "1048576.0 GiB"]


def test_a_resumed_scan_writes_a_byte_identical_dataset_with_the_camera_description(tmp_path):
    from ringlight.core.capture.workflow import resume_scan

    windows, plan, notes = analytic_windows(), scan_plan(), "camera: backend simulated, bits 12"
    mapping = identity_mapping(SimulatedRig(windows), plan.roi)
    whole = Scan(tmp_path / "whole", plan, mapping, notes)
    whole.prepare(resume=False)
    rig = SimulatedRig(windows)
    whole.run(rig.camera, rig.projector)
    part = Scan(tmp_path / "part", plan, mapping, notes)
    part.prepare(resume=False)
    stop_after = iter(range(100))
    rig = SimulatedRig(windows)
    with pytest.raises(Cancelled):
        part.run(rig.camera, rig.projector, should_stop=lambda: next(stop_after) >= 7)
    resumed = resume_scan(tmp_path / "part")  # as the CLI's --resume: everything from the folder
    assert resumed.camera_notes == notes
    resumed.prepare(resume=True)
    rig = SimulatedRig(windows)
    resumed.run(rig.camera, rig.projector)
    assert (tmp_path / "part/dataset.json").read_bytes() == (tmp_path / "whole/dataset.json").read_bytes()
    assert json.loads((tmp_path / "part/dataset.json").read_text())["notes"].endswith(notes)
    assert frame_files(tmp_path / "part") == frame_files(tmp_path / "whole")


def test_a_torn_journal_line_does_not_swallow_the_next_entry(tmp_path):
    windows = analytic_windows()
    stop_after = iter(range(100))
    with pytest.raises(Cancelled):
        run_scan(tmp_path / "scan", SimulatedRig(windows), should_stop=lambda: next(stop_after) >= 5)
    journal = tmp_path / "scan/.scan/journal.jsonl"
    with open(journal, "a") as handle:
        handle.write('{"index": 5, "fi')  # a line torn by a power cut
    rig = SimulatedRig(windows)
    scan = Scan(tmp_path / "scan", scan_plan(), identity_mapping(rig, scan_plan().roi))
    scan.prepare(resume=True)
    stop_after = iter(range(100))
    with pytest.raises(Cancelled):
        scan.run(rig.camera, rig.projector, should_stop=lambda: next(stop_after) >= 1)
    # The entry written after the repair (frame 5) stands on a line of its own and counts.
    assert [json.loads(line)["index"] for line in journal.read_text().splitlines()] == [0, 1, 2, 3, 4, 5]
    assert sorted(scan.finished_frames()) == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize("failure", ["oserror", "library"])
def test_a_disk_that_fills_inside_a_frame_write_pauses_the_scan_with_one_line(tmp_path, monkeypatch, capsys, failure):
    import errno

    from ringlight.core.capture import scan as scan_module

    real_write = scan_module.write_exr_rgb
    writes = iter(range(100))

    def filling_disk(path, image):
        if next(writes) >= 4:  # dark frame and three frames fit
            if failure == "oserror":
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            # What the OpenEXR library raises (measured on a full 64 KiB tmpfs).
            raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')
        real_write(path, image)

    monkeypatch.setattr(scan_module, "write_exr_rgb", filling_disk)
    with pytest.raises(ScanPaused) as paused:
        run_scan(tmp_path / "scan", SimulatedRig(analytic_windows()))
    message = str(paused.value)
    assert message.startswith("scan paused after 3 of 49 frames: ") and "\n" not in message
    assert f"{tmp_path}/scan/frames/00003.exr" in message and "No space left on device" in message
    assert message.endswith("; free some space (or fix the folder) and resume")
    assert not [path for path in (tmp_path / "scan").rglob("*") if ".partial-" in path.name]
    monkeypatch.setattr(scan_module, "write_exr_rgb", real_write)
    resumed = run_scan(tmp_path / "scan", SimulatedRig(analytic_windows()), resume=True)
    whole = run_scan(tmp_path / "whole", SimulatedRig(analytic_windows()))
    assert frame_files(resumed) == frame_files(whole)


def test_the_capture_command_prints_one_line_when_the_disk_fills(tmp_path, monkeypatch, capsys):
    import errno

    from ringlight.core.capture import scan as scan_module

    def full_disk(path, image):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(scan_module, "write_exr_rgb", full_disk)
    status = main(["capture", "--camera", "simulated", "--projector", "simulated", "--option", "size=8x8",
                   "--option", "photons=100", "--max-radius", "2", "--out", str(tmp_path / "scan")])
    err = capsys.readouterr().err
    assert status == 2 and "Traceback" not in err
    assert err.strip().splitlines()[-1] == (
        f"ringlight: error: scan paused after 0 of 25 frames: {tmp_path}/scan/dark.exr: cannot write here: "
        "No space left on device; free some space (or fix the folder) and resume")


def test_a_folder_deleted_during_a_scan_is_not_made_again_and_a_fresh_run_completes(tmp_path):
    import shutil

    from ringlight.core.capture.workflow import resume_scan

    out = tmp_path / "scan"
    calls = iter(range(100))

    def delete_the_folder():
        if next(calls) == 3:
            shutil.rmtree(out)
        return False

    with pytest.raises(ScanError, match="scan's folder was removed during the scan"):
        run_scan(out, SimulatedRig(analytic_windows()), should_stop=delete_the_folder)
    assert not out.exists()
    with pytest.raises(ScanError, match="no unfinished scan to resume .*start the scan again"):
        resume_scan(out)
    fresh = run_scan(out, SimulatedRig(analytic_windows()))
    whole = run_scan(tmp_path / "whole", SimulatedRig(analytic_windows()))
    assert frame_files(fresh) == frame_files(whole)


@pytest.mark.parametrize("users", [
    {"mapping.exr": b"my own mapping", ".scan/notes.txt": b"my notes"},
    {".mapping.partial-0123456789ab.exr": b"my hidden file"},
    {"frames/thesis.tex": b"precious"},
    {"..scan.partial-0123456789ab/plan.json": b"{}"},
])
def test_a_new_scan_never_deletes_or_replaces_a_users_files(tmp_path, users):
    """Issue 40, case 1: a folder holding a user's mapping.exr and .scan/notes.txt had them taken
    for an interrupted preparation (notes.txt deleted, mapping.exr replaced), and a user's
    .mapping.partial-0123456789ab.exr deleted. A new scan writes only into an absent or empty
    folder; anything else is one line and every byte stays."""
    out = tmp_path / "scan"
    for name, data in users.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    before = {path.relative_to(out).as_posix(): path.read_bytes() for path in out.rglob("*") if path.is_file()}
    with pytest.raises(ScanError, match=r"scan: exists and is not empty \(it holds .+\); refusing") as refused:
        run_scan(out, SimulatedRig(analytic_windows()))
    assert "\n" not in str(refused.value)
    after = {path.relative_to(out).as_posix(): path.read_bytes() for path in out.rglob("*") if path.is_file()}
    assert after == before == users
    assert sorted(path.name for path in tmp_path.iterdir()) == ["scan"]  # no staging folder left beside


def test_an_abandoned_preparation_is_swept_and_a_users_look_alike_is_kept(tmp_path, monkeypatch):
    """A preparation killed outright leaves the output folder as it was and its unlocked staging
    folder beside it; the next new scan of that folder removes it (once no process holds its lock
    and it is older than ABANDONED_AGE, here 0), but never a look-alike holding a user's file."""
    from ringlight.core import staging_locks

    monkeypatch.setattr(staging_locks, "ABANDONED_AGE", 0.0)
    abandoned = tmp_path / ".scan.partial-0123456789ab"
    (abandoned / "frames").mkdir(parents=True)
    (abandoned / "mapping.exr").write_bytes(b"half a mapping")
    (abandoned / ".scan").mkdir()
    (abandoned / ".scan" / "plan.json").write_text("{}")
    users = tmp_path / ".scan.partial-abcdef012345"
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    (tmp_path / "scan").mkdir()  # empty: a new scan may be published onto it
    out = run_scan(tmp_path / "scan", SimulatedRig(analytic_windows()))
    assert sorted(path.name for path in out.iterdir()) == [".scan", "dark.exr", "dataset.json", "frames", "mapping.exr"]
    assert sorted(path.name for path in tmp_path.iterdir()) == [".scan.partial-abcdef012345", "scan"]
    assert (users / "notes.txt").read_text() == "mine"


def test_a_resumed_scan_removes_only_the_temporaries_of_its_own_files(tmp_path):
    out = tmp_path / "scan"
    stop_after = iter(range(100))
    with pytest.raises(Cancelled):
        run_scan(out, SimulatedRig(analytic_windows()), should_stop=lambda: next(stop_after) >= 3)
    torn = [out / ".dark.partial-0123456789ab.exr", out / "frames/.00004.partial-0123456789ab.exr"]
    users = [out / ".thesis.partial-0123456789ab.tex", out / "frames/.notes.partial-0123456789ab.txt"]
    for path in torn + users:
        path.write_bytes(b"bytes")
    run_scan(out, SimulatedRig(analytic_windows()), resume=True)
    assert [path.exists() for path in torn + users] == [False, False, True, True]


KILLER = r"""
# Runs a reference scan, then scans into OUT_k, each in a forked child killed with SIGKILL before
# its k-th file-system step; at a frame write or journal append the step first leaves the file
# torn. k runs over every step of the preparation and its publication, every step from the
# saturation map on, and a random third (seeded by argv[3]) of the steps between. Forking from
# this fresh process (nothing but imports run) keeps each kill cheap; fsync is a step but does
# nothing, since a SIGKILL loses nothing the kernel holds.
import json, os, random, signal, sys
import numpy as np
from ringlight.core.capture import scan as scan_module
from ringlight.core.capture.scan import Scan
from ringlight.core.capture.scan_plan import ScanPlan
from ringlight.core.capture.simulated_rig import SimulatedRig
from ringlight.core.colourspaces import is_known_colourspace

folder = sys.argv[1]
plan = ScanPlan(*json.loads(sys.argv[2]))
windows, mapping = np.load(os.path.join(folder, "windows.npy")), np.load(os.path.join(folder, "mapping.npy"))
is_known_colourspace("sRGB")  # loads colour-science once, before forking
kill_at, count = 0, 0

def step(torn=None):
    global count
    count += 1
    if count == kill_at:
        if torn is not None:
            torn()
        os.kill(os.getpid(), signal.SIGKILL)

def counted(function):
    def wrapper(*args, **kwargs):
        step()
        return function(*args, **kwargs)
    return wrapper

def torn_exr(write):
    def wrapper(path, *args, **kwargs):
        step(lambda: open(path, "wb").write(b"v/1 torn"))
        write(path, *args, **kwargs)
    return wrapper

def torn_append(append):
    def wrapper(scan, entry):
        step(lambda: open(scan.journal_path, "a").write('{"index": %d, "fi' % entry["index"]))
        append(scan, entry)
    return wrapper

def scan_into(out):
    for name in ("mkdir", "rename", "replace", "link", "unlink", "rmdir"):
        setattr(os, name, counted(getattr(os, name)))
    os.fsync = counted(lambda descriptor: None)
    scan_module.write_exr_rgb = torn_exr(scan_module.write_exr_rgb)
    scan_module.write_exr_channels = torn_exr(scan_module.write_exr_channels)
    Scan._append_journal = torn_append(Scan._append_journal)
    rig = SimulatedRig(windows)
    scan = Scan(out, plan, mapping, "camera: simulated test rig")
    scan.prepare(resume=False)
    prepared = count
    scan.run(rig.camera, rig.projector)
    with open(os.path.join(folder, "steps.json"), "w") as handle:
        json.dump([prepared, count], handle)

def child(out, at):
    global kill_at
    pid = os.fork()
    if pid == 0:
        kill_at = at
        try:
            scan_into(out)
        finally:
            os._exit(0)
    return os.waitpid(pid, 0)[1]

assert child(os.path.join(folder, "reference"), 0) == 0
prepared, total = json.load(open(os.path.join(folder, "steps.json")))
chance = random.Random(int(sys.argv[3]))
points = [at for at in range(1, total + 1) if at <= prepared + 1 or at > total - 16 or chance.random() < 1 / 3]
statuses = {at: child(os.path.join(folder, f"out_{at}"), at) for at in points}
print(json.dumps({"prepared": prepared, "total": total, "points": points,
                  "killed": [at for at, status in statuses.items() if os.WIFSIGNALED(status)]}))
"""


def test_a_capture_killed_at_any_step_resumes_or_restarts_to_the_same_dataset(tmp_path, monkeypatch):
    import subprocess

    from ringlight.core.capture.workflow import resume_scan

    monkeypatch.setattr(os, "fsync", lambda descriptor: None)  # durability is not what is tested here
    windows = analytic_windows()
    plan = ScanPlan((2, 2, 8, 8), 1.0, (0.05,))  # 9 frames, every lit point saturated: masks written
    mapping = identity_mapping(SimulatedRig(windows), plan.roi)
    np.save(tmp_path / "windows.npy", windows)
    np.save(tmp_path / "mapping.npy", mapping)
    seed = int(os.environ.get("RINGLIGHT_KILL_SEED", "0"))
    result = subprocess.run([sys.executable, "-c", KILLER, str(tmp_path), json.dumps(
        [plan.roi, plan.max_radius, plan.exposures]), str(seed)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    # Every chosen step was a kill point: from creating the folder through publishing .scan, a
    # random third of the frames, masks and journal entries, and the saturation map and the
    # manifest's publication at the end.
    assert report["prepared"] >= 10 and report["killed"] == report["points"]
    assert set(range(1, report["prepared"] + 2)) <= set(report["points"])
    reference = tmp_path / "reference"
    expected = {path.relative_to(reference).as_posix(): path.read_bytes()
                for path in sorted(reference.rglob("*")) if path.is_file()}
    assert len([name for name in expected if name.startswith(".scan/saturated/")]) == 9
    for at in report["killed"]:
        out = tmp_path / f"out_{at}"
        rig = SimulatedRig(windows)
        if (out / ".scan/plan.json").is_file():
            scan = resume_scan(out)  # as --resume does: plan, notes and mapping from the folder
            scan.prepare(resume=True)
        else:
            with pytest.raises(ScanError, match="no unfinished scan to resume"):
                resume_scan(out)
            scan = Scan(out, plan, mapping, "camera: simulated test rig")
            scan.prepare(resume=False)  # never "exists and is not empty" for ringlight's leftovers
        scan.run(rig.camera, rig.projector)
        got = {path.relative_to(out).as_posix(): path.read_bytes() for path in sorted(out.rglob("*")) if path.is_file()}
        assert got == expected, f"killed before step {at}: {sorted(set(got) ^ set(expected))}"


def test_the_projector_check_reports_a_dimming_projectors_drift(tmp_path):
    rig = SimulatedRig(analytic_windows())
    plan = scan_plan()
    reference = plan.pattern(plan.frames()[0], rig.size)
    truth = []  # the brightness of each showing of the reference pattern: the drift to find

    class DimmingProjector:
        """The rig's projector losing 0.3 % of its light with every pattern shown."""

        def __init__(self, projector):
            self.projector, self.shows = projector, 0

        def __getattr__(self, name):
            return getattr(self.projector, name)

        def show(self, pattern):
            brightness = 1 - 0.003 * self.shows
            self.shows += 1
            if np.array_equal(pattern, reference):
                truth.append(brightness)
            self.projector.show(pattern * brightness)

    scan = Scan(tmp_path / "scan", plan, identity_mapping(rig, plan.roi), check_every=10)
    scan.prepare(resume=False)
    reported = []
    scan.run(rig.camera, DimmingProjector(rig.projector), progress=lambda state: reported.append(state.drift))
    drifts = scan.projector_check.drifts()
    assert [entry["frame"] for entry in scan.projector_check.entries()] == [0, 10, 20, 30, 40, 49]
    # The checks are the reference pattern's showings but the second (frame 0 itself, after check 0).
    expected = np.array(truth[:1] + truth[2:]) / truth[0] - 1
    # Shot and read noise: 0.16 % of a check's radiance (measured over 30 repeats), 0.23 % for a
    # drift (two checks): 3 sigma is 0.7 %. Measured: largest error 0.42 %.
    np.testing.assert_allclose(drifts, expected, atol=0.007)
    assert reported[-1] == pytest.approx(drifts[-2]) and drifts[-1] < -0.1
    notes = json.loads((tmp_path / "scan/dataset.json").read_text())["notes"]
    assert f"radiance {drifts.min():+.2%} to +0.00% of the first" in notes


def test_the_time_estimate_counts_every_capture_a_scan_makes(tmp_path):
    """The plan's estimate (frames, dark frame, projector checks; each bracket an exposure plus
    the camera's overhead) against the captures a real scan makes, counted: with no overhead or
    settling it is their exposure time, and each second of overhead per capture adds one second
    per capture. (The wizard's 40 s for an 8 s scan came from an overhead guessed, not measured.)"""
    rig = SimulatedRig(analytic_windows())
    exposures = []
    capture = rig.camera.capture
    rig.camera.capture = lambda exposure: (exposures.append(exposure), capture(exposure))[1]
    plan = scan_plan()
    scan = Scan(tmp_path / "out", plan, identity_mapping(rig, plan.roi), check_every=7)
    scan.prepare(resume=False)
    scan.run(rig.camera, rig.projector)
    assert len(exposures) > len(plan.frames()) * len(plan.exposures)  # frames, dark and checks all counted
    assert plan.estimated_seconds(0.0, 0.0, 7) == pytest.approx(sum(exposures), rel=1e-9)
    assert plan.estimated_seconds(1.0, 0.0, 7) - plan.estimated_seconds(0.0, 0.0, 7) == pytest.approx(len(exposures))
