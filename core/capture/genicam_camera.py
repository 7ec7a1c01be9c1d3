"""The ``genicam`` camera backend: any vendor's GenTL producer through ``harvesters``.

A GenTL producer is the vendor's ``.cti`` library (installed with its SDK); ``harvesters``
(``pip install 'ringlight[genicam]'``) loads it and exposes the camera's GenICam node map, whose
SFNC features :class:`.SfncCamera` uses. Frames are software-triggered one at a time.

Options (strings): ``cti`` (path of the producer; default: the ``GENICAM_GENTL64_PATH``
environment variable's first ``.cti``), ``serial``, ``pixel_format``, ``frame_timeout``.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np

from .hardware import HardwareError, HardwarePlugin
from .machine_vision import SfncCamera

INSTALL_HINT = ("harvesters is not installed: pip install 'ringlight[genicam]' (or pip install harvesters), "
                "plus your camera vendor's GenTL producer (.cti)")


def _sdk():
    """(Harvester class, timeout exception class) of harvesters; HardwareError when absent."""
    try:
        from genicam.gentl import TimeoutException
        from harvesters.core import Harvester
    except ImportError:
        raise HardwareError(f"genicam camera: {INSTALL_HINT}") from None
    return Harvester, TimeoutException


def default_cti() -> str:
    """The first ``.cti`` file in the folders of ``GENICAM_GENTL64_PATH`` (the GenTL standard's
    variable), or "" when there is none."""
    for folder in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
        if folder and Path(folder).is_dir():
            found = sorted(Path(folder).glob("*.cti"))
            if found:
                return str(found[0])
    return ""


class GenICamCamera(SfncCamera):
    """A GenTL camera (see the module docstring).

    ``sdk``: (Harvester class, timeout exception class); by default harvesters' own (tests pass
    fakes with the same interface).
    """

    def __init__(self, cti: str = "", serial: str = "", pixel_format: str = "", frame_timeout: str = "5", sdk=None):
        self.cti = cti or default_cti()
        self.serial = serial
        self.name = f"genicam camera {serial}".strip()
        super().__init__(pixel_format, frame_timeout)
        self.sdk = sdk
        self.harvester = self.acquirer = None

    def _connect(self) -> dict[str, str]:
        harvester_class, _ = self.sdk or _sdk()
        if not self.cti or not Path(self.cti).is_file():
            raise HardwareError(f"genicam camera: no GenTL producer at {self.cti!r}; give its .cti path "
                                "as the cti option (or set GENICAM_GENTL64_PATH)")
        self.harvester = harvester_class()
        self.harvester.add_file(self.cti)
        self.harvester.update()
        devices = list(self.harvester.device_info_list)
        matches = [index for index, info in enumerate(devices) if not self.serial or info.serial_number == self.serial]
        if not matches:
            found = ", ".join(info.serial_number for info in devices) or "none"
            self._disconnect()
            raise HardwareError(f"genicam ({Path(self.cti).name}): no camera with serial {self.serial!r}; found {found}")
        info = devices[matches[0]]
        self.serial = info.serial_number
        self.name = f"genicam camera {self.serial}"
        self.acquirer = self.harvester.create(matches[0])
        for name, value in (("TriggerSelector", "FrameStart"), ("TriggerMode", "On"), ("TriggerSource", "Software")):
            if self._feature_range(name) is not None:
                self._set_feature(name, value)
        return {"backend": f"genicam {Path(self.cti).name}", "model": f"{info.vendor} {info.model}".strip(),
                "serial": self.serial}

    def _disconnect(self) -> None:
        if self.acquirer is not None:
            if self.acquirer.is_acquiring():
                self.acquirer.stop()
            self.acquirer.destroy()
            self.acquirer = None
        if self.harvester is not None:
            self.harvester.reset()
            self.harvester = None

    def _node(self, name: str):
        try:
            return getattr(self.acquirer.remote_device.node_map, name)
        except Exception:  # GenApi raises its own LogicalErrorException for an unknown feature
            return None

    def _feature(self, name: str):
        try:
            return self._node(name).value
        except Exception as error:  # any GenApi failure to read is the camera's problem, reported
            raise HardwareError(f"{self.name}: reading {name}: {error}") from None

    def _set_feature(self, name: str, value) -> None:
        try:
            self._node(name).value = value
        except Exception as error:  # GenApi refuses out-of-range values and locked features
            raise HardwareError(f"{self.name}: setting {name} to {value}: {error}") from None

    def _feature_range(self, name: str):
        node = self._node(name)
        if node is None:
            return None
        if hasattr(node, "symbolics"):
            return tuple(node.symbolics)
        if hasattr(node, "min"):
            return (float(node.min), float(node.max))
        return ()

    def _grab(self, timeout_s: float) -> np.ndarray:
        _, timeout_class = self.sdk or _sdk()
        try:
            if not self.acquirer.is_acquiring():
                self.acquirer.start()
            if self._node("TriggerSoftware") is not None:
                self._node("TriggerSoftware").execute()
            with self.acquirer.fetch(timeout=timeout_s) as buffer:
                component = buffer.payload.components[0]
                channels = 3 if self.pixel_format.startswith("RGB") else 1
                samples = np.asarray(component.data, np.uint16)
                return samples[:component.height * component.width * channels].reshape(
                    component.height, component.width * channels).copy()
        except timeout_class:
            self.acquirer.stop()  # a late frame must not be taken for the next one
            raise HardwareError(f"{self.name}: no frame within {timeout_s:g} s (frame timeout)") from None
        except HardwareError:
            raise
        except Exception as error:  # GenTL errors of a device gone: reported as a disconnect
            raise HardwareError(f"{self.name}: disconnected or failed: {type(error).__name__}: {error}") from None


PLUGIN = HardwarePlugin(
    name="genicam",
    cameras={"genicam": GenICamCamera},
    description="any GenTL camera through harvesters (options: cti, serial, pixel_format, frame_timeout)",
    unavailable="" if importlib.util.find_spec("harvesters") else INSTALL_HINT,
)
