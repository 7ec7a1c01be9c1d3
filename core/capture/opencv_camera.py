"""The ``opencv`` camera backend: any camera ``cv2.VideoCapture`` can open (webcams, UVC).

Such cameras deliver 8-bit, usually gamma-encoded frames with automatic gain: fine for trying a
rig, not for measurements (use a linear machine-vision camera through its own plugin). Exposure is
set through ``CAP_PROP_EXPOSURE`` where the backend accepts it; where it does not,
:meth:`OpenCVCamera.properties` says so and every capture uses the camera's own exposure.
"""

from __future__ import annotations

import cv2
import numpy as np

from .hardware import HardwareError, HardwarePlugin


class OpenCVCamera:
    """``index``: the VideoCapture device index (a string, as typed)."""

    def __init__(self, index: str = "0"):
        try:
            self.index = int(index)
        except ValueError:
            raise HardwareError(f"opencv camera: index must be an integer, got {index!r}") from None
        self.capture_device: cv2.VideoCapture | None = None
        self.exposure_control = False
        self._shape: tuple[int, ...] = (0, 0, 3)

    def open(self) -> None:
        device = cv2.VideoCapture(self.index)
        if not device.isOpened():
            raise HardwareError(f"opencv camera: no camera at index {self.index}")
        ok, frame = device.read()
        if not ok:
            device.release()
            raise HardwareError(f"opencv camera {self.index}: opened but delivers no frames")
        self.capture_device = device
        self._shape = frame.shape if frame.ndim == 3 else (*frame.shape, 3)
        # Manual exposure where the backend allows it (V4L2: auto-exposure 1 = manual).
        device.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)
        self.exposure_control = bool(device.set(cv2.CAP_PROP_EXPOSURE, -6))

    def close(self) -> None:
        if self.capture_device is not None:
            self.capture_device.release()
            self.capture_device = None

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return self._shape

    @property
    def exposure_range(self) -> tuple[float, float]:
        return (1e-4, 1.0)

    @property
    def saturation_level(self) -> float:
        return 255.0

    @property
    def black_level(self) -> float:
        return 0.0

    def properties(self) -> dict[str, str]:
        return {
            "backend": f"opencv VideoCapture {self.index}",
            "bits": "8 (gamma not removed)",
            "exposure control": "yes" if self.exposure_control else "no: the camera's automatic exposure is used",
        }

    def capture(self, exposure: float) -> np.ndarray:
        if self.capture_device is None:
            raise HardwareError("opencv camera: not open")
        if self.exposure_control:
            # CAP_PROP_EXPOSURE is log2 seconds on most backends.
            self.capture_device.set(cv2.CAP_PROP_EXPOSURE, float(np.log2(exposure)))
        ok, frame = self.capture_device.read()
        if not ok:
            raise HardwareError(f"opencv camera {self.index}: stopped delivering frames")
        if frame.ndim == 2:
            frame = np.repeat(frame[:, :, None], 3, axis=2)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB).astype(np.float32)


PLUGIN = HardwarePlugin(
    name="opencv",
    cameras={"opencv": lambda index="0": OpenCVCamera(index)},
    description="cameras through cv2.VideoCapture (option: index)",
)
