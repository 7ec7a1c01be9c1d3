"""The ``spinnaker`` camera backend: FLIR (Point Grey) cameras through PySpin.

The paper's camera was a Point Grey Grasshopper3. PySpin is not on PyPI: it comes with FLIR's
Spinnaker SDK (the ``spinnaker_python`` wheel from flir.com); without it the plugin is listed as
unavailable with that one line. Frames are software-triggered one at a time; everything else is
:class:`.SfncCamera`.

Options (strings): ``serial``, ``pixel_format``, ``frame_timeout``.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from .hardware import HardwareError, HardwarePlugin
from .machine_vision import SfncCamera

INSTALL_HINT = ("PySpin is not installed: install FLIR's Spinnaker SDK and its Python wheel "
                "(spinnaker_python, from flir.com; not on PyPI)")


def _sdk():
    try:
        import PySpin
    except ImportError:
        raise HardwareError(f"spinnaker camera: {INSTALL_HINT}") from None
    return PySpin


class SpinnakerCamera(SfncCamera):
    """A FLIR camera (see the module docstring); ``sdk``: the PySpin module (tests pass a fake)."""

    def __init__(self, serial: str = "", pixel_format: str = "", frame_timeout: str = "5", sdk=None):
        self.serial = serial
        self.name = f"spinnaker camera {serial}".strip()
        super().__init__(pixel_format, frame_timeout)
        self.sdk = sdk
        self.system = self.cameras = self.camera = None

    def _connect(self) -> dict[str, str]:
        spin = self.sdk or _sdk()
        self.system = spin.System.GetInstance()
        self.cameras = self.system.GetCameras()
        found = [self.cameras.GetByIndex(index) for index in range(self.cameras.GetSize())]
        serials = [camera.TLDevice.DeviceSerialNumber.GetValue() for camera in found]
        if self.serial and self.serial not in serials or not serials:
            del found  # PySpin refuses to release the system while camera references live
            self._disconnect()
            raise HardwareError(f"spinnaker: no camera with serial {self.serial!r}; found {', '.join(serials) or 'none'}")
        index = serials.index(self.serial) if self.serial else 0
        self.camera, self.serial = found[index], serials[index]
        self.name = f"spinnaker camera {self.serial}"
        try:
            self.camera.Init()
        except spin.SpinnakerException as error:
            self._disconnect()
            raise HardwareError(f"{self.name}: cannot open: {error}") from None
        for name, value in (("TriggerMode", "Off"), ("TriggerSelector", "FrameStart"), ("TriggerSource", "Software"),
                            ("TriggerMode", "On")):  # FLIR cameras take the trigger source only with the mode off
            if self._feature_range(name) is not None:
                self._set_feature(name, value)
        model = self.camera.TLDevice.DeviceModelName.GetValue()
        return {"backend": f"spinnaker {self.system.GetLibraryVersion().major}", "model": model, "serial": self.serial}

    def _disconnect(self) -> None:
        if self.camera is not None:
            if self.camera.IsStreaming():
                self.camera.EndAcquisition()
            if self.camera.IsInitialized():
                self.camera.DeInit()
            self.camera = None  # PySpin needs every camera reference gone before the release
        if self.cameras is not None:
            self.cameras.Clear()
            self.cameras = None
        if self.system is not None:
            self.system.ReleaseInstance()
            self.system = None

    def _node(self, name: str):
        spin = self.sdk or _sdk()
        node = self.camera.GetNodeMap().GetNode(name)
        if node is None or not spin.IsAvailable(node):
            return None
        pointer = {spin.intfIFloat: spin.CFloatPtr, spin.intfIInteger: spin.CIntegerPtr,
                   spin.intfIEnumeration: spin.CEnumerationPtr, spin.intfIString: spin.CStringPtr,
                   spin.intfICommand: spin.CCommandPtr}.get(node.GetPrincipalInterfaceType())
        return pointer(node) if pointer is not None else None

    def _feature(self, name: str):
        spin = self.sdk or _sdk()
        node = self._node(name)
        if node is None:
            raise HardwareError(f"{self.name}: has no readable {name}")
        try:
            return node.GetCurrentEntry().GetSymbolic() if hasattr(node, "GetCurrentEntry") else node.GetValue()
        except spin.SpinnakerException as error:
            raise HardwareError(f"{self.name}: reading {name}: {error}") from None

    def _set_feature(self, name: str, value) -> None:
        spin = self.sdk or _sdk()
        node = self._node(name)
        try:
            if node is None:
                raise HardwareError(f"{self.name}: has no {name}")
            if hasattr(node, "GetEntryByName"):
                entry = node.GetEntryByName(value)
                if entry is None:
                    raise HardwareError(f"{self.name}: {name} has no entry {value}")
                node.SetIntValue(entry.GetValue())
            else:
                node.SetValue(value)
        except spin.SpinnakerException as error:
            raise HardwareError(f"{self.name}: setting {name} to {value}: {error}") from None

    def _feature_range(self, name: str):
        spin = self.sdk or _sdk()
        node = self._node(name)
        if node is None:
            return None
        if hasattr(node, "GetEntries"):
            return tuple(entry.GetSymbolic() for entry in map(spin.CEnumEntryPtr, node.GetEntries())
                         if spin.IsAvailable(entry))
        if hasattr(node, "GetMin"):
            return (float(node.GetMin()), float(node.GetMax()))
        return ()

    def _grab(self, timeout_s: float) -> np.ndarray:
        spin = self.sdk or _sdk()
        camera = self.camera
        try:
            if not camera.IsStreaming():
                camera.BeginAcquisition()
            self._node("TriggerSoftware").Execute()
            image = camera.GetNextImage(int(round(timeout_s * 1000)))
        except spin.SpinnakerException as error:
            if error.errorcode == spin.SPINNAKER_ERR_TIMEOUT:
                camera.EndAcquisition()  # a late frame must not be taken for the next one
                raise HardwareError(f"{self.name}: no frame within {timeout_s:g} s (frame timeout)") from None
            if not camera.IsValid():
                raise HardwareError(f"{self.name}: disconnected") from None
            raise HardwareError(f"{self.name}: grab failed: {error}") from None
        try:
            if image.IsIncomplete():
                raise HardwareError(f"{self.name}: incomplete frame (status {image.GetImageStatus()})")
            samples = np.asarray(image.GetNDArray(), np.uint16)
            return samples.reshape(image.GetHeight(), -1).copy()
        finally:
            image.Release()


PLUGIN = HardwarePlugin(
    name="spinnaker",
    cameras={"spinnaker": SpinnakerCamera},
    description="FLIR cameras through PySpin (options: serial, pixel_format, frame_timeout)",
    unavailable="" if importlib.util.find_spec("PySpin") else INSTALL_HINT,
)
