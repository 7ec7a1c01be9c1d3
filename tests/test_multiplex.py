"""Hadamard S-matrix multiplexing: the code, demultiplexing within the predicted noise, and a
multiplexed scan whose dataset matches a plain one."""

import numpy as np
import pytest
from ringlight.app.main import main
from ringlight.core import open_dataset
from ringlight.core.capture.multiplex import (
    code_blocks,
    coded_lit,
    demultiplex,
    predicted_variance,
    s_matrix,
    s_matrix_inverse,
)
from ringlight.core.capture.scan import Scan
from ringlight.core.capture.scan_plan import ScanError, ScanPlan, check_plan
from ringlight.core.capture.simulated_rig import CameraSampling, SensorModel, SimulatedRig
from test_capture import analytic_windows, identity_mapping


@pytest.mark.parametrize("order", [3, 7, 15, 31])
def test_s_matrix_has_half_its_points_lit_and_the_closed_form_inverse(order):
    code = s_matrix(order)
    assert set(code.sum(axis=1)) == {(order + 1) // 2}
    np.testing.assert_allclose(s_matrix_inverse(order) @ code, np.eye(order), atol=1e-12)
    # Harwit and Sloane: every entry of S^-1 is +-2/(n+1), so the variance factor is 4n/(n+1)^2.
    assert np.allclose(np.abs(s_matrix_inverse(order)), 2 / (order + 1))


def test_blocks_keep_the_frame_count_and_an_odd_tail_is_captured_plainly():
    blocks = code_blocks(17, 7)
    assert [list(indices) for indices, _ in blocks] == [list(range(7)), list(range(7, 14)), [14], [15], [16]]
    assert [code is None for _, code in blocks] == [False, False, True, True, True]
    with pytest.raises(ScanError, match="order 2"):
        check_plan(ScanPlan((0, 0, 8, 8), 2.0, (0.01,), multiplex=6), (8, 8))


def test_multiplexed_frames_demultiplex_to_the_single_impulses_within_the_predicted_noise():
    # One camera pixel per grid point, no saturation: the comparison is pixel by pixel.
    sensor = SensorModel(read_noise=8.0, black_level=100.0, bits=20)
    rig = SimulatedRig(analytic_windows(16, 3), CameraSampling(1.0, 0.0, (0.0, 0.0), 0), sensor)
    plan = ScanPlan((0, 0, 16, 16), 3.0, (0.002,))
    indices, code = code_blocks(len(plan.frames()), 7)[0]
    captures = []
    for lit in coded_lit(plan.frames(), indices, code):
        rig.projector.show(plan.pattern(lit, rig.size))
        captures.append(rig.camera.capture(0.002) - sensor.black_level)
    recovered = demultiplex(np.stack(captures), code)
    # The truth: each lattice frame's expected electrons, from the scene's noise-free radiance.
    truth = np.stack([rig.scene_radiance(plan.pattern(plan.frames()[j], rig.size)) for j in indices])
    truth *= sensor.gain * 0.002
    capture_variance = sensor.read_noise**2 + 1 / 12 + np.tensordot(code, truth, axes=1)  # read, rounding, shot
    z = (recovered - truth) / np.sqrt(predicted_variance(capture_variance, code))
    # 5376 samples: the standard error of the mean is 0.014 and of the standard deviation 0.010.
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1) < 0.04


def test_a_multiplexed_scan_writes_the_lattice_frames_of_a_plain_scan(tmp_path):
    windows = analytic_windows()
    datasets = {}
    for multiplex in (0, 7):
        rig = SimulatedRig(windows)
        plan = ScanPlan((2, 2, 14, 14), 3.0, (0.002, 0.008), noise_floor=6.0, multiplex=multiplex)
        scan = Scan(tmp_path / f"scan{multiplex}", plan, identity_mapping(rig, plan.roi))
        scan.prepare(resume=False)
        datasets[multiplex] = open_dataset(scan.run(rig.camera, rig.projector), use_cache=False)
        # Projector checks every 25 frames, before the block holding frame 25 (frames 21-27 when coded).
        assert [entry["frame"] for entry in scan.projector_check.entries()] == [0, 21 if multiplex else 25, 49]
    plain, coded = datasets[0].responses, datasets[7].responses
    assert len(datasets[7].manifest.frames) == len(datasets[0].manifest.frames) == 49
    near = np.abs(plain) > 0.05 * np.nanmax(plain)  # where the impulse responses hold light
    difference = (coded - plain)[near] / np.nanmean(np.abs(plain)[near])
    # Measured: mean |difference| 4.0 % (two plain scans of other seeds: 1.3 %): this bright scan is
    # shot-noise limited, where a response far from its lit point carries the shot noise of the
    # neighbouring lit points of its block (the loss bench_multiplex.py measures); mean -0.9 %.
    assert np.nanmean(np.abs(difference)) < 0.06 and abs(np.nanmean(difference)) < 0.02


def test_the_capture_command_refuses_an_order_without_a_code_before_opening_devices(capsys):
    assert main(["capture", "--camera", "simulated", "--projector", "simulated", "--option", "fail_after=0",
                 "--multiplex", "6", "--out", "unused"]) == 2
    assert "needs order 2^k - 1 from 3 to 1023 (3, 7, 15, 31, ...), got 6" in capsys.readouterr().err


@pytest.mark.parametrize("order", [2047, 65535])
def test_a_code_too_large_is_refused_before_opening_devices_and_any_matrix(capsys, order):
    """Issue 40, case 7: --multiplex 65535 asked for a 32 GiB matrix after 16.5 GB of captures."""
    import tracemalloc

    tracemalloc.start()
    status = main(["capture", "--camera", "simulated", "--projector", "simulated", "--option", "fail_after=0",
                   "--multiplex", str(order), "--out", "unused"])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert status == 2 and peak < 64 * 2**20
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"ringlight: error: a Hadamard S-matrix code needs order 2^k - 1 from 3 to 1023 (3, 7, 15, 31, ...), "
        f"got {order}")


def test_a_block_whose_captures_do_not_fit_the_memory_budget_is_refused_before_the_scan(tmp_path, monkeypatch):
    """A block of 1023 captures of a 48 x 48 camera region holds 1023 x 48 x 48 x 12 x 6 bytes
    (161.8 MiB) at once: refused under a 128 MiB budget, accepted under 256 MiB."""
    from ringlight.core.capture.scan import Scan
    from ringlight.core.capture.scan_plan import ScanError, ScanPlan

    mapping = np.zeros((48, 48, 2), np.float32)
    plan = ScanPlan((0, 0, 24, 24), 1.0, (0.05,), multiplex=1023)
    monkeypatch.setenv("RINGLIGHT_MEMORY_BUDGET", "256M")
    Scan(tmp_path / "fits", plan, mapping)
    monkeypatch.setenv("RINGLIGHT_MEMORY_BUDGET", "128M")
    with pytest.raises(ScanError, match=r"a block of 1023 multiplexed captures of 48 x 48 pixels holds 161.8 MiB"):
        Scan(tmp_path / "too-large", plan, mapping)
