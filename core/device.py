"""Which device runs the photon kernels and the stacks: the CPU, or an NVIDIA GPU through numba's
CUDA target (the ``ringlight[cuda]`` extra installs NVIDIA's ``numba-cuda``).

``auto`` takes a GPU when one is usable (numba's CUDA target finds a driver and a device) and
the CPU otherwise; ``cuda`` insists on one. numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``)
counts as a device for ``cuda`` only, so that the CUDA kernels can be tested without a GPU,
never for ``auto`` (it runs a kernel in Python, thousands of times slower than the CPU kernels).
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import RinglightError

CHOICES = ("auto", "cpu", "cuda")
"""What ``--device`` takes."""


class DeviceError(RinglightError):
    """The device asked for cannot run."""


@dataclass(frozen=True)
class Device:
    """A device kernels run on.

    Attributes
    ----------
    kind
        ``"cpu"`` or ``"cuda"``.
    name
        What ran, for the output and the notes: ``"CPU (16 cores)"``, ``"NVIDIA H100 80GB HBM3"``,
        ``"CUDA simulator"``.
    """

    kind: str
    name: str

    @property
    def is_cuda(self) -> bool:
        return self.kind == "cuda"


def cpu_device() -> Device:
    """The CPU, with the cores numba's parallel kernels use."""
    import numba

    return Device("cpu", f"CPU ({numba.config.NUMBA_NUM_THREADS} cores)")


def cuda_device() -> Device | None:
    """The current CUDA device (or numba's CUDA simulator when enabled), None when none is usable:
    numba's CUDA target missing, no driver, or no device."""
    try:
        from numba import cuda
    except ImportError:
        return None
    if simulator_enabled():
        return Device("cuda", "CUDA simulator")
    # is_available() is False when the driver or the target's libraries fail to load.
    if not cuda.is_available() or len(cuda.gpus) == 0:
        return None
    name = cuda.get_current_device().name
    return Device("cuda", name.decode() if isinstance(name, bytes) else str(name))


def simulator_enabled() -> bool:
    """Whether numba runs CUDA kernels in its simulator (``NUMBA_ENABLE_CUDASIM=1`` when numba was
    first imported)."""
    import numba

    return bool(numba.config.ENABLE_CUDASIM)


def choose_device(choice: str = "auto") -> Device:
    """The device for ``choice`` (one of :data:`CHOICES`): ``auto`` a usable GPU (not the
    simulator), else the CPU; ``cuda`` a usable GPU or the simulator, else DeviceError."""
    if choice not in CHOICES:
        raise DeviceError(f"unknown device {choice!r}: expected one of {', '.join(CHOICES)}")
    if choice == "cpu":
        return cpu_device()
    if choice == "auto" and simulator_enabled():
        return cpu_device()
    device = cuda_device()
    if device is not None:
        return device
    if choice == "cuda":
        raise DeviceError("--device cuda: no usable NVIDIA GPU (install ringlight[cuda], and check the driver "
                          "with nvidia-smi)")
    return cpu_device()
