"""The CUDA kernels' runs for tests/test_cuda_kernels.py, each saved to an .npz: in this process
when it has a usable GPU, else in a child process under numba's CUDA simulator
(NUMBA_ENABLE_CUDASIM must be set before numba is first imported, and the simulator runs each
thread as a Python thread, which the test process's leak guard would count).

Run as ``python cuda_cases.py CASE OUT.npz [ARGUMENT]``; exits 3 when the simulator is missing.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

UNAVAILABLE = 3


def radial(out: Path, argument: str) -> None:
    """The radial white run's kernel: 12 photons on 4 streams of seed 3 (n 1.4, g 0.5)."""
    from ringlight.core.optics.radial_cuda import run_radial_cuda

    run = run_radial_cuda(1.4, 0.5, 12, seed=3, streams=4)
    np.savez(out, weight=run.weight, rho=run.rho, path=run.path, photons=run.photons)


def white(out: Path, argument: str) -> None:
    """The layered slab's white run kernel: 256 photons on 4 streams of seed 2, an index-matched
    isotropic slab of mus 1 per grid step, 8 grid steps deep, records within 5 pixels."""
    from ringlight.core.inversion.white_cuda import run_white_cuda
    from ringlight.core.inversion.white_mc import SlabOptics

    run = run_white_cuda(SlabOptics((1.0,), 0.0, 1.0, 8.0, 5), 256, seed=2, streams=4)
    np.savez(out, pixel=run.pixel, value=run.value, lengths=run.lengths, photon=run.photon, photons=run.photons)


def stacks(out: Path, argument: str) -> None:
    """The ring and transient stacks of the dataset at ``argument`` (radius 4.5), radii 0..3."""
    from ringlight.core import open_dataset
    from ringlight.core.device import choose_device
    from ringlight.core.rings.stacks import ring_and_transient_stacks

    ring, transient = ring_and_transient_stacks(open_dataset(argument, radius=4.5), np.arange(4.0), 1.0,
                                                device=choose_device("cuda"))
    np.savez(out, ring=ring.images, transient=transient.images, counts=ring.counts)


def device(out: Path, argument: str) -> None:
    from ringlight.core.device import choose_device

    np.savez(out, name=choose_device("cuda").name, auto=choose_device("auto").kind)


CASES = {"radial": radial, "white": white, "stacks": stacks, "device": device}


def run_case(case: str, out: Path, argument: str = "") -> dict[str, np.ndarray] | None:
    """Run ``case`` on a GPU of this process or in the simulator; its arrays, or None when
    neither is there."""
    from ringlight.core.device import cuda_device

    if cuda_device() is not None:
        CASES[case](out, argument)
    else:
        env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
        done = subprocess.run([sys.executable, __file__, case, str(out), argument], env=env, capture_output=True,
                              text=True, timeout=600)
        if done.returncode == UNAVAILABLE:
            return None
        assert done.returncode == 0, done.stderr[-3000:]
    with np.load(out) as arrays:
        return dict(arrays)


if __name__ == "__main__":
    try:
        import numba.cuda  # the simulator (numba's own, or numba-cuda's) must import
    except ImportError:
        sys.exit(UNAVAILABLE)
    assert numba.cuda.is_available()  # True in the simulator
    # The simulator adds the generator's uint64 words as numpy scalars, whose wrap-around (intended:
    # arithmetic modulo 2^64, as on the device) numpy reports as an overflow.
    warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning)
    CASES[sys.argv[1]](Path(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "")
