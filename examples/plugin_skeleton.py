"""A hardware plugin skeleton
==========================

Copy it into your lab's package and fill in the device calls.
``python examples/plugin_skeleton.py`` checks the skeleton against ringlight's protocols.

Register it in your package's pyproject.toml and ringlight lists it in the wizard and the CLI::

    [project.entry-points."ringlight.hardware"]
    mylab = "mylab_rig.ringlight_plugin:PLUGIN"
"""

import numpy as np
from ringlight.core.capture.hardware import (
    Camera,
    HardwareError,
    HardwarePlugin,
    Projector,
)


class MyCamera:
    """A linear 12-bit monochrome camera; replace the bodies with your SDK's calls."""

    frame_shape = (480, 640)  # (rows, cols) or (rows, cols, 3)
    exposure_range = (1e-5, 10.0)  # seconds
    saturation_level = 4095.0  # raw counts
    black_level = 64.0  # raw counts of no light

    def __init__(self, serial: str = "0"):  # factories receive the KEY=VALUE options as strings
        self.serial = serial

    def open(self) -> None: ...

    def close(self) -> None: ...

    def properties(self) -> dict[str, str]:
        return {"model": "my camera", "serial": self.serial, "bits": "12"}

    def capture(self, exposure: float) -> np.ndarray:
        """One frame of float32 raw counts exposed for ``exposure`` seconds."""
        raise HardwareError(f"camera {self.serial}: capture is not written yet")


class MyProjector:
    """A projector showing float patterns in [0, 1] of shape ``size``."""

    size = (768, 1024)  # (rows, cols) of projector pixels
    settle_time = 0.05  # seconds between showing a pattern and capturing

    def open(self) -> None: ...

    def close(self) -> None: ...

    def show(self, pattern: np.ndarray) -> None: ...

    def show_black(self) -> None: ...

    def show_white(self) -> None: ...


PLUGIN = HardwarePlugin(name="mylab", cameras={"mylab-cam": MyCamera}, projectors={"mylab-projector": MyProjector})

if __name__ == "__main__":
    camera, projector = PLUGIN.cameras["mylab-cam"](serial="1234"), PLUGIN.projectors["mylab-projector"]()
    print(f"camera follows the protocol: {isinstance(camera, Camera)}")
    print(f"projector follows the protocol: {isinstance(projector, Projector)}")
