"""Progressive, resumable simulation (issue 12): photons are added until the estimated noise
reaches the target; an interrupted run keeps its photons and continues; the noise estimate is
honest against an independent run."""

from __future__ import annotations

import numpy as np
import pytest
from ringlight.app.main import main
from ringlight.core.errors import Cancelled
from ringlight.core.simulate.convergence import transient_noise
from ringlight.core.simulate.progressive import checkpoint_path, fingerprint, load_checkpoint, simulate_until
from ringlight.core.simulate.scene import parse_scene
from ringlight.core.simulate.transport import simulate_transport


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(tmp_path / "cache"))


def slab(size=10, max_radius=4):
    return parse_scene({
        "format": "ringlight-scene", "version": 1, "grid": {"height": size, "width": size}, "depth": 20, "n": 1.4,
        "materials": {"m": {"mus": [1.0] * 3, "mua": [0.02, 0.05, 0.1]}}, "background": "m",
        "max_radius": max_radius, "seed": 4,
    }, name="slab")


def test_photons_are_added_until_the_noise_target_and_the_estimate_is_honest():
    scene = slab()
    statuses = []
    transport, status = simulate_until(scene, target=0.1, batch=20, estimator="analogue", report=statuses.append)
    assert status.worst <= 0.1 and all(s.worst > 0.1 for s in statuses[7:-1])
    assert len(statuses) >= 8 and statuses[1].worst > statuses[-1].worst
    assert transport.photons == status.photons == 20 * len(statuses)
    # An independent simulation of as many photons: the actual noise of the result, measured
    # from the pair (each of them noisy like the result), agrees with the estimate within 2x.
    other = simulate_transport(scene, photons=transport.photons, seed=99, estimator="analogue")
    actual = transient_noise(transport.windows.astype(np.float64), other.windows.astype(np.float64), range(4))
    assert np.all(status.noise / 2 < actual) and np.all(actual < status.noise * 2), (status.noise, actual)
    # Success removes nothing by itself: the caller forgets the checkpoint once the dataset is written.
    assert checkpoint_path(fingerprint(scene, scene.seed, 20, "analogue")).exists()


def test_an_interrupted_run_keeps_its_photons_and_continues_to_the_same_result():
    scene = slab()
    whole, _ = simulate_until(scene, seconds=1e-9, batch=3)  # the least: two batches
    fresh = slab()
    key = checkpoint_path(fingerprint(fresh, fresh.seed, 3, "reference"))
    key.unlink()

    def cancel(fraction):
        raise Cancelled("stop")

    simulate_until(fresh, seconds=1e-9, batch=3)  # two batches, saved
    with pytest.raises(Cancelled):
        simulate_until(fresh, seconds=1e9, batch=3, progress=cancel)
    assert load_checkpoint(key).batches == 2  # the batch in flight is lost, the others kept
    statuses = []
    resumed, status = simulate_until(fresh, seconds=1e-9, batch=3, report=statuses.append)
    assert statuses[0].resumed and resumed.photons == 6
    np.testing.assert_array_equal(resumed.windows, whole.windows)


def test_the_command_line_simulates_to_a_noise_target_and_cleans_up(tmp_path, capsys):
    out = tmp_path / "ds"
    assert main(["simulate", "layers3", "--size", "12x12", "--out", str(out), "--noise", "0.2",
                 "--photons", "5"]) == 0
    err = capsys.readouterr().err
    assert "noise of T_" in err and (out / "dataset.json").exists()
    assert not list((tmp_path / "cache" / "simulations").glob("*.npz"))
    assert main(["simulate", "layers3", "--out", str(tmp_path / "x"), "--time", "soon"]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    assert main(["simulate", "layers3", "--out", str(tmp_path / "x"), "--noise", "5"]) == 2


def test_a_run_to_a_noise_target_on_a_grid_smaller_than_its_rings_stops():
    """Issue 40, case 9: on a 4 x 4 grid the rings beyond the grid are NaN everywhere, their
    noise never known: "noise of T_r up to r = 11 at most inf" for good. The noise is measured up
    to the largest r whose ring r + 1 has a member on the grid: brute force over the offsets."""
    from ringlight.core.rings.geometry import ring_geometry
    from ringlight.core.simulate.progressive import noise_radius
    from ringlight.core.simulate.presets import load_scene

    scene = load_scene("layers3", size=(4, 4))  # max_radius 12
    defined = [r for r in range(12) if any(abs(dy) < 4 and abs(dx) < 4 for dy, dx in ring_geometry(r + 1.0).offsets)]
    assert noise_radius(scene) == max(defined) == 3
    batches = []

    def count(fraction):
        if fraction >= 1.0:  # a batch ends
            batches.append(1)
        if len(batches) > 400:
            raise Cancelled("did not stop")

    _, status = simulate_until(scene, target=0.25, batch=5, progress=count)
    assert status.worst <= 0.25 and len(status.noise) == 4 and np.isfinite(status.noise).all()
    assert 8 <= len(batches) <= 400
