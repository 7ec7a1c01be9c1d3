"""The CUDA kernels against the CPU kernels: on a GPU when this machine has one, else in numba's
CUDA simulator (tiny problems: it runs each thread in Python). Run by :mod:`cuda_cases`.

The same photons on the same streams give the CPU's sums up to rounding: the order of the sums,
and on a GPU the multiply-adds that its compiler fuses (FMA) where the CPU rounds twice. An H100
gave path means 1.1e-12 apart, relative; :data:`SAME_WALKS` allows 1e-9.
"""

from dataclasses import replace

import numpy as np
import pytest
from cuda_cases import run_cases
from numpy.testing import assert_allclose
from reference import random_impulses, write_dataset
from test_adding_doubling import chandrasekhar_h_at_one
from ringlight.core import open_dataset
from ringlight.core.device import DeviceError, choose_device, cuda_device, simulator_enabled
from ringlight.core.inversion import white_mc
from ringlight.core.optics import radial
from ringlight.core.rings.stacks import ring_and_transient_stacks
from ringlight.core.simulate.streams import ESTIMATOR_STREAM, seed_state, walk_and_estimator_states


SAME_WALKS = {"rtol": 1e-9, "atol": 1e-15}
"""Tolerance of a GPU's sums of the photons that the CPU walks on the same streams (module notes)."""


@pytest.fixture(scope="module")
def gpu_runs(tmp_path_factory):
    """``(runs, folder)``: every case's arrays by name, run once for the module (in the simulator, all
    in one process), and the folder that holds the stacks case's dataset ``ds`` and the simulate
    command's ``sim``."""
    folder = tmp_path_factory.mktemp("cuda")
    impulses = random_impulses(np.random.default_rng(4), 6, 7, support=40, missing=0.2)
    write_dataset(folder / "ds", 6, 7, impulses)
    cases = {case: "" for case in ("radial", "white", "cells", "simulate_points", "simulate_differences",
                                   "mcml_slab", "device")}
    runs = run_cases(cases | {"stacks": str(folder / "ds"), "simulate_command": str(folder / "sim")}, folder)
    return runs, folder


def cuda_case(case, gpu_runs):
    runs, _ = gpu_runs
    if runs is None:
        pytest.skip("numba's CUDA simulator is not available")
    if isinstance(runs[case], str):
        pytest.fail(f"the {case} case failed:\n{runs[case]}", pytrace=False)
    return runs[case]


def test_gpu_runs_seed_their_threads_as_the_cpu_seeds_each_stream():
    # The states a GPU run sends (compiled, all at once) are seed_state's, stream by stream.
    streams = np.array([0, 1, 5, 32767, (1 << 40) - 1])
    states = walk_and_estimator_states(7, streams)
    expected = [seed_state(7, int(s)) for s in streams] + [seed_state(7, int(s) + ESTIMATOR_STREAM) for s in streams]
    assert states.dtype == np.uint64 and np.array_equal(states, np.stack(expected))
    assert len(np.unique(states, axis=0)) == 2 * len(streams)


def test_radial_kernel_walks_the_cpus_photons_on_the_same_streams(gpu_runs):
    # Thread t walks stream (seed, t) with the same compiled steps: the CPU's block kernel on
    # streams 0..3 makes the same cell sums (up to the order of the additions). 12 photons are
    # rounded up as the CPU rounds them (whole blocks: 16), 4 on each stream.
    gpu = cuda_case("radial", gpu_runs)
    assert int(gpu["photons"]) == radial.traced_photons(12) == 16
    weight, rho_sum, path_sum = (np.zeros((radial.RHO_CELLS, radial.PATH_CELLS)) for _ in range(3))
    for stream in range(4):
        radial._radial_block(0.5, 1.4, radial.LONGEST / 0.5, 4, 3, stream, weight, rho_sum, path_sum)
    assert weight.sum() > 0
    assert_allclose(gpu["weight"], weight, rtol=SAME_WALKS["rtol"], atol=1e-18)
    with np.errstate(invalid="ignore", divide="ignore"):
        assert_allclose(gpu["rho"], np.where(weight > 0, rho_sum / weight, 0.0), **SAME_WALKS)
        assert_allclose(gpu["path"], np.where(weight > 0, path_sum / weight, 0.0), **SAME_WALKS)


def test_white_kernel_makes_the_cpus_records_and_chandrasekhars_reflectance(gpu_runs):
    gpu = cuda_case("white", gpu_runs)
    # (1) Thread t walks stream (seed 2, t) and its estimator stream, photons 64 t .. 64 t + 63:
    # the CPU's block kernel on those streams makes the same records in the same order.
    optics = white_mc.SlabOptics((1.0,), 0.0, 1.0, 8.0, 5)
    parts = []
    for stream in range(4):
        arguments = (np.array(optics.mus), optics.g, optics.n, optics.depth, optics.reach, 64, 64 * stream, 2, stream)
        count = white_mc._white_block(*arguments, np.zeros(0, np.int32), np.zeros(0, np.float32),
                                      np.zeros((0, 1), np.float32), np.zeros(0, np.int32))
        records = (np.zeros(count, np.int32), np.zeros(count, np.float32), np.zeros((count, 1), np.float32),
                   np.zeros(count, np.int32))
        white_mc._white_block(*arguments, *records)
        parts.append(records)
    pixel, value, lengths, photon = (np.concatenate([part[i] for part in parts]) for i in range(4))
    assert int(gpu["photons"]) == 256 and len(photon) > 1000
    assert np.array_equal(gpu["pixel"], pixel) and np.array_equal(gpu["photon"], photon)
    assert_allclose(gpu["value"], value, rtol=1e-6)
    assert_allclose(gpu["lengths"], lengths, rtol=1e-6)
    # (2) Reweighted for absorption mua = mus (albedo 1/2), the records' sum per photon is the
    # normal radiance of an index-matched isotropic half-space, omega H(1)^2 / 8 (Chandrasekhar
    # 1960; the same check as the optics table's white run): 0.09785. The slab's depth and reach
    # cut off below 0.1 % of it (the CPU with 10^5 photons: 0.09793 +- 0.00036). 256 photons
    # leave a standard error of about 7 % (itself uncertain: the estimates are heavy-tailed).
    per_photon = np.bincount(gpu["photon"], gpu["value"] * np.exp(-gpu["lengths"][:, 0]), 256)
    error = per_photon.std() / np.sqrt(256)
    assert abs(per_photon.mean() - 0.5 * chandrasekhar_h_at_one(0.5) ** 2 / 8) < 3 * error


def test_cells_kernel_tallies_the_records_the_cpu_walks_on_the_same_streams(gpu_runs):
    # The GPU tallies each estimate into its cell as it walks (a hash table, atomic adds); the
    # reference tallies with numpy the records of the same photons (the records kernel's, which
    # are the CPU's on these streams), launch by launch (seed 5 + (launch << 32)), each record's
    # batch its photon's number modulo 16. The table starts at 16 slots and has to grow.
    from cuda_cases import CELLS_OPTICS
    from ringlight.core.inversion.forward import Structure
    from ringlight.core.inversion.white_cells import BATCHES, cell_moments, pixel_classes, tally_records

    gpu = cuda_case("cells", gpu_runs)
    optics, structure = white_mc.SlabOptics(**CELLS_OPTICS), Structure((0, 1))
    classes = pixel_classes(optics.reach)
    keys, sums, batches = [], [], []
    for launch in range(2):
        records = white_mc.WhiteDatabase(optics, 32, *(gpu[f"launch{launch}_{name}"]
                                                       for name in ("pixel", "value", "lengths", "photon")), 0.0)
        unique, moments = tally_records(records, structure, classes)
        weight = np.zeros((len(unique), BATCHES))
        for batch in range(BATCHES):
            mine = records.photon % BATCHES == batch
            part = replace(records, pixel=records.pixel[mine], value=records.value[mine],
                           lengths=records.lengths[mine], photon=records.photon[mine])
            part_keys, part_moments = tally_records(part, structure, classes)
            weight[np.searchsorted(unique, part_keys), batch] = part_moments[:, 0]
        keys.append(unique)
        sums.append(moments)
        batches.append(weight)
    cells, inverse = np.unique(np.concatenate(keys), return_inverse=True)
    total, batch_weight = np.zeros((len(cells), sums[0].shape[1])), np.zeros((len(cells), BATCHES))
    np.add.at(total, inverse, np.concatenate(sums))
    np.add.at(batch_weight, inverse, np.concatenate(batches))
    cpu = cell_moments(optics, structure, 64, cells, total, batch_weight, 0.0)
    assert int(gpu["photons"]) == 64 and len(cells) > 64  # more cells than the first table's 16 slots
    assert np.array_equal(gpu["cell_class"], cpu.cell_class)
    for name in ("weight", "mean", "spread"):
        assert_allclose(gpu[name], getattr(cpu, name), **SAME_WALKS)
    assert_allclose(gpu["batch_weight"], cpu.batch_weight, rtol=1e-5, atol=1e-9)


def test_stack_kernel_equals_the_cpu_stacks(gpu_runs):
    # A 6 x 7 dataset with missing points: the gather kernel's ring and transient images against
    # core.rings' (same sums in another order: float32 rounding), NaN in the same places.
    gpu, folder = cuda_case("stacks", gpu_runs), gpu_runs[1]
    ring, transient = ring_and_transient_stacks(open_dataset(folder / "ds", radius=4.5), np.arange(4.0), 1.0)
    for name, cpu in (("ring", ring.images), ("transient", transient.images)):
        assert np.array_equal(np.isnan(gpu[name]), np.isnan(cpu))
        assert np.isnan(cpu).any() and not np.isnan(cpu).all()
        assert_allclose(np.nan_to_num(gpu[name]), np.nan_to_num(cpu), rtol=1e-5, atol=1e-7)
    assert np.array_equal(gpu["counts"], ring.counts)


def test_simulator_points_kernel_walks_the_cpus_photons_on_the_same_streams(gpu_runs):
    # Thread i walks lit point i on stream (seed 9, streams[i]) and its estimator stream, through
    # the same compiled walk: the CPU kernel's windows and path-length images, up to the order of
    # the atomic sums, in a heterogeneous volume (voxel traversal of the estimate), two channels,
    # oblique projector and camera, either measure.
    from cuda_cases import simulator_volume
    from ringlight.core.simulate.camera import optics
    from ringlight.core.simulate.photon import simulate_points

    gpu = cuda_case("simulate_points", gpu_runs)
    volume, tables, majorant, lit, streams = simulator_volume()
    for measure in ("camera", "exitance"):
        windows, truth = np.zeros((3, 5, 5, 2)), np.zeros((2, 8, 5, 5, 2))
        simulate_points(volume, tables, majorant, optics(1.4, 6.0, (20.0, 30.0), (25.0, 10.0)),
                        np.zeros((0, 0, 0, 0)), measure == "camera", lit, 20, 9, streams, 4.0, windows, truth)
        assert np.count_nonzero(windows) > 10 and np.count_nonzero(truth) > 10
        assert_allclose(gpu[f"{measure}_windows"], windows, **SAME_WALKS)
        assert_allclose(gpu[f"{measure}_truth"], truth.sum(axis=0), **SAME_WALKS)


def test_simulator_differences_kernel_equals_the_cpus_correlated_differences(gpu_runs):
    # The scene's walk, its save at the first marked voxel and the reference walk from there on the
    # saved streams: the CPU's differences and touch counts, a direct point scored whole.
    from cuda_cases import run_differences

    gpu = cuda_case("simulate_differences", gpu_runs)
    windows, truth = np.zeros((3, 5, 5, 2)), np.zeros((2, 8, 5, 5, 2))
    touches = run_differences(windows, truth)
    assert touches[1] == 0 and touches.sum() > 0 and np.count_nonzero(windows) > 10
    assert np.array_equal(gpu["touches"], touches)
    assert_allclose(gpu["windows"], windows, **SAME_WALKS)
    assert_allclose(gpu["truth"], truth.sum(axis=0), **SAME_WALKS)


def test_simulator_kernel_gives_mcmls_slab_reflectance(gpu_runs):
    # MCML manual Table 6.1 (the CPU simulator's test_mcml_slab_diffuse_reflectance_matches_van_de_hulst):
    # n = 1, mu_a = 10, mu_s = 90 per unit, g = 0.75, 0.02 deep: R_d = 0.09739 (van de Hulst 1980).
    # 1024 photons on 16 streams, the exitance within one pixel of the lit one (the slab is 2 mean
    # free paths deep: light leaves within 0.1 pixel of where it entered). The standard error from
    # the spread of the 16 streams' means is about 8 %; the CPU on the same streams agrees exactly.
    from ringlight.core.simulate.camera import optics
    from ringlight.core.simulate.photon import simulate_points
    from ringlight.core.simulate.tables import single_channel_tables

    gpu = cuda_case("mcml_slab", gpu_runs)
    tables, majorant = single_channel_tables([100.0], [0.9], [0.75])
    windows = np.zeros((16, 3, 3, 1))
    simulate_points(np.zeros((1, 1, 1), np.uint8), tables, majorant, optics(1.0, 0.02), np.zeros((0, 0, 0, 0)),
                    False, np.zeros((16, 2), np.int64), 64, 7, np.arange(16), 1.0, windows, np.zeros((1, 0, 1, 1, 1)))
    assert_allclose(gpu["windows"], windows, **SAME_WALKS)
    per_stream = gpu["windows"].sum(axis=(1, 2, 3)) / 64
    error = per_stream.std(ddof=1) / np.sqrt(16)
    assert 0 < error < 0.02 and abs(per_stream.mean() - 0.09739) < 3 * error, (per_stream.mean(), error)


def test_simulate_command_on_cuda_names_the_device_in_its_output_and_notes(gpu_runs):
    # The whole command through the GPU path (the reference kernel on the device's streams): a
    # dataset whose notes and output line name the device.
    arrays = cuda_case("simulate_command", gpu_runs)
    name = cuda_device().name if cuda_device() is not None else "CUDA simulator"
    assert int(arrays["status"]) == 0
    assert str(arrays["printed"]).rstrip().endswith(f"M photons/s) on {name}")
    assert f"\nphotons traced on {name}" in str(arrays["notes"])
    responses = open_dataset(gpu_runs[1] / "sim").point(1, 1)
    assert np.isfinite(responses).all() and responses.sum() > 0


def test_cuda_device_is_the_gpu_or_the_simulator_and_auto_never_the_simulator(gpu_runs):
    arrays = cuda_case("device", gpu_runs)
    usable = cuda_device()
    assert str(arrays["name"]) == (usable.name if usable is not None else "CUDA simulator")
    assert str(arrays["auto"]) == ("cuda" if usable is not None else "cpu")


@pytest.mark.skipif(cuda_device() is not None or simulator_enabled(), reason="a GPU is usable here")
def test_without_a_gpu_auto_is_the_cpu_and_cuda_a_one_line_error():
    assert choose_device("auto").kind == "cpu"
    assert choose_device("cpu").name.startswith("CPU (")
    with pytest.raises(DeviceError, match="^--device cuda: no usable NVIDIA GPU") as error:
        choose_device("cuda")
    assert "\n" not in str(error.value)
    with pytest.raises(DeviceError, match="unknown device 'gpu'"):
        choose_device("gpu")


def test_stack_command_says_which_device_summed_the_rings(tmp_path, capsys):
    from ringlight.app.main import main

    impulses = random_impulses(np.random.default_rng(5), 5, 6, support=2.5, missing=0.0)
    write_dataset(tmp_path / "ds", 5, 6, impulses, max_radius=2.5)
    assert main(["stack", str(tmp_path / "ds"), "--radii", "0:1:1", "--device", "cpu", "--out",
                 str(tmp_path / "cpu")]) == 0
    assert "; rings summed on CPU (" in capsys.readouterr().out
    # Without a GPU (or with one but together with --interpolate), --device cuda is one line, exit 2.
    status = main(["stack", str(tmp_path / "ds"), "--radii", "0:1:1", "--device", "cuda", "--interpolate",
                   "--out", str(tmp_path / "gpu")])
    error = capsys.readouterr().err
    assert status == 2 and "--device cuda" in error and "--interpolate" in error
    assert not (tmp_path / "gpu").exists()


@pytest.mark.skipif(cuda_device() is not None or simulator_enabled(), reason="a GPU is usable here")
@pytest.mark.parametrize("command", [["layers", "DATASET", "--method", "inverse"],
                                     ["optics", "DATASET", "--json", "OUT"],
                                     ["simulate", "homogeneous", "--size", "3x3", "--out", "OUT"]])
def test_device_cuda_without_a_gpu_stops_the_white_runs_commands_in_one_line(tmp_path, capsys, command):
    from ringlight.app.main import main

    arguments = [str(tmp_path / "out.json") if part == "OUT" else str(tmp_path / "missing") if part == "DATASET"
                 else part for part in command]
    assert main([*arguments, "--device", "cuda"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.endswith("--device cuda: no usable NVIDIA GPU (install ringlight[cuda], and check the driver with "
                          "nvidia-smi)") and "\n" not in error
    assert not (tmp_path / "out.json").exists()
