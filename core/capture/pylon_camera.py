"""The ``pylon`` camera backend: Basler cameras through ``pypylon`` (``pip install ringlight[pylon]``).

Cameras are enumerated and opened by serial number (the first one when none is given). Frames are
software-triggered one at a time (``TriggerMode`` On, ``TriggerSource`` Software), so every frame
is exposed after the projector shows its pattern; everything else is :class:`.SfncCamera`.

pylon's camera emulation stands in for a camera: with the environment variable
``PYLON_CAMEMU=N`` set before enumeration, pypylon lists N emulated cameras ("0815-0000", ...).
Their image-file mode (``ImageFileMode`` On, ``ImageFilename``) delivers the frames of a file through
the real SDK path; the option ``feed=simulated`` uses it to show an emulated camera what the
simulated rig's camera sees (see :class:`SimulatedFeed`), so a whole scan runs against the SDK.

Options (strings): ``serial``, ``pixel_format`` (Mono12, Mono16, BayerRG12, ..., RGB16Packed),
``frame_timeout`` (seconds beyond the exposure), ``feed`` and, with ``feed=simulated``, the
simulated rig's options (``scene``, ``size``, ``photons``, ``seed``, ``fail_after``).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np

from .hardware import HardwareError, HardwarePlugin
from .machine_vision import SfncCamera, format_bits, is_colour_format

INSTALL_HINT = "pypylon is not installed: pip install 'ringlight[pylon]' (or pip install pypylon)"
EMULATOR_CLASS = "BaslerCamEmu"


def _pylon():
    """(pylon, genicam) modules of pypylon; HardwareError naming what to install when absent."""
    with warnings.catch_warnings():
        # pypylon's SWIG modules warn at import (no __module__ on their builtin types), and
        # under "warnings as errors" the half-initialised extension crashes the interpreter.
        warnings.filterwarnings("ignore", message="builtin type [Ss]wig", category=DeprecationWarning)
        try:
            from pypylon import genicam, pylon
        except ImportError:
            raise HardwareError(f"pylon camera: {INSTALL_HINT}") from None
    return pylon, genicam


def list_cameras() -> list[dict[str, str]]:
    """The cameras pylon sees: ``{"serial", "model", "class"}`` each (emulated ones included when
    ``PYLON_CAMEMU`` is set)."""
    pylon, _ = _pylon()
    return [{"serial": device.GetSerialNumber(), "model": device.GetModelName(), "class": device.GetDeviceClass()}
            for device in pylon.TlFactory.GetInstance().EnumerateDevices()]


class SimulatedFeed:
    """The simulated rig's camera frames, written where pylon's camera emulator reads them.

    Each :meth:`write` captures the rig at ``exposure`` seconds (noise, black level, 12 bits)
    and writes a 16-bit TIFF whose values are the 12-bit counts shifted left by 4: the emulator
    delivers a 12-bit format as the file's values shifted right by 4 (measured with pypylon
    26.9), so the frame arrives unchanged. Mono formats get the mean of R, G, B rounded; Bayer
    formats get the RGB file, which the emulator mosaics.
    """

    def __init__(self, camera):
        self.camera = camera
        """The simulated camera whose frames it delivers (:class:`.simulated_rig.SimulatedCamera`)."""
        self.folder: Path | None = None  # made at the first write, removed by close

    @property
    def path(self) -> Path:
        return self.folder / "frame.tiff"

    def write(self, exposure: float, pixel_format: str) -> Path:
        counts = self.camera.capture(exposure)  # (rows, cols, 3) 12-bit counts as float32
        if not is_colour_format(pixel_format):
            counts = np.round(counts.mean(axis=-1))
        image = counts.astype(np.uint16) << 4
        if self.folder is None:
            self.folder = Path(tempfile.mkdtemp(prefix="ringlight-pylon-feed-"))
        temporary = self.folder / "next.tiff"
        if not cv2.imwrite(str(temporary), image if image.ndim == 2 else image[..., ::-1]):
            raise HardwareError(f"pylon emulator feed: cannot write {temporary}")
        os.replace(temporary, self.path)
        return self.path

    def close(self) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


class PylonCamera(SfncCamera):
    """A Basler camera (see the module docstring); ``feed``: a :class:`SimulatedFeed` or None."""

    def __init__(self, serial: str = "", pixel_format: str = "", frame_timeout: str = "5",
                 feed: SimulatedFeed | None = None):
        self.serial = serial
        self.name = f"pylon camera {serial}".strip()
        if feed is not None and pixel_format and format_bits(pixel_format) != feed.camera.sensor.bits:
            raise HardwareError(f"{self.name}: the simulated feed is {feed.camera.sensor.bits}-bit; "
                                f"choose a {feed.camera.sensor.bits}-bit pixel format, not {pixel_format}")
        super().__init__(pixel_format or ("Mono12" if feed is not None else ""), frame_timeout)
        self.feed = feed
        self.camera = None

    @property
    def simulated_scene(self) -> dict[str, str] | None:
        """The options of the simulated rig the feed shows, or None (:func:`.simulated_rig.pair_problem`)."""
        return None if self.feed is None else self.feed.camera.simulated_scene

    def properties(self) -> dict[str, str]:
        """The camera's description (:class:`.machine_vision.SfncCamera`), and the simulated rig it is fed."""
        if self.feed is None:
            return super().properties()
        from .simulated_rig import describe_rig

        return {**super().properties(), "feed": describe_rig(self.feed.camera.simulated_scene)}

    def pair_problem(self, projector) -> str | None:
        """Why a fed camera cannot film what ``projector`` shows (the feed's camera's answer), or None."""
        return None if self.feed is None else self.feed.camera.pair_problem(projector)

    def _connect(self) -> dict[str, str]:
        pylon, genicam = _pylon()
        factory = pylon.TlFactory.GetInstance()
        devices = factory.EnumerateDevices()
        chosen = [d for d in devices if not self.serial or d.GetSerialNumber() == self.serial]
        if not chosen:
            found = ", ".join(d.GetSerialNumber() for d in devices) or "none (set PYLON_CAMEMU=1 to emulate one)"
            raise HardwareError(f"pylon: no camera with serial {self.serial!r}; found {found}")
        device = chosen[0]
        self.serial = device.GetSerialNumber()
        self.name = f"pylon camera {self.serial}"
        if self.feed is not None and device.GetDeviceClass() != EMULATOR_CLASS:
            raise HardwareError(f"{self.name}: feed=simulated needs an emulated camera (PYLON_CAMEMU), "
                                f"not a {device.GetModelName()}")
        try:
            self.camera = pylon.InstantCamera(factory.CreateDevice(device))
            self.camera.Open()
            if self.feed is not None:
                self._set_feature("TestImageSelector", "Off")
                self._set_feature("ImageFileMode", "On")
                self._set_feature("ImageFilename", str(self.feed.write(self.feed.camera.sensor.exposure_range[0],
                                                                       self.pixel_format)))
                rows, cols = self.feed.camera.frame_shape[:2]
                self._set_feature("Width", cols)
                self._set_feature("Height", rows)
                self._set_feature("BlackLevel", self.feed.camera.sensor.black_level)
            for name, value in (("TriggerSelector", "FrameStart"), ("TriggerMode", "On"), ("TriggerSource", "Software")):
                if self._feature_range(name) is not None:
                    self._set_feature(name, value)
        except genicam.GenericException as error:
            self._disconnect()
            raise HardwareError(f"{self.name}: cannot open: {_first_line(error)}") from None
        return {"backend": f"pylon {pylon.GetPylonVersionString()}", "model": device.GetModelName(),
                "serial": self.serial}

    def _configure(self) -> None:
        super()._configure()
        if self.feed is not None:
            low, high = self._exposure_range
            sim_low, sim_high = self.feed.camera.sensor.exposure_range
            self._exposure_range = (max(low, sim_low), min(high, sim_high))

    def _disconnect(self) -> None:
        if self.camera is not None:
            try:
                self.camera.StopGrabbing()
                self.camera.Close()
            finally:
                self.camera = None
        if self.feed is not None:
            self.feed.close()

    def _node(self, name: str):
        return self.camera.GetNodeMap().GetNode(name)

    def _feature(self, name: str):
        return self._guarded(lambda: self._node(name).GetValue(), f"reading {name}")

    def _set_feature(self, name: str, value) -> None:
        self._guarded(lambda: self._node(name).SetValue(value), f"setting {name} to {value}")

    def _feature_range(self, name: str):
        _, genicam = _pylon()
        node = self._node(name)
        if not genicam.IsAvailable(node):
            return None
        if hasattr(node, "Symbolics"):
            return tuple(node.Symbolics)
        if hasattr(node, "GetMin"):
            return (float(node.GetMin()), float(node.GetMax()))
        return ()

    def capture(self, exposure: float) -> np.ndarray:
        if self.feed is not None and self.is_open:
            low, high = self._exposure_range
            if low <= exposure <= high:
                # The emulator reads its image file when grabbing starts (measured): restart it.
                self._guarded(self.camera.StopGrabbing, "stopping the grab")
                self.feed.write(exposure, self.pixel_format)
        return super().capture(exposure)

    def _grab(self, timeout_s: float) -> np.ndarray:
        pylon, genicam = _pylon()
        camera = self.camera
        timeout_ms = int(round(timeout_s * 1000))
        try:
            if not camera.IsGrabbing():
                camera.StartGrabbing(pylon.GrabStrategy_OneByOne)
            # A trigger sent before the camera is ready is lost: wait for readiness first.
            camera.WaitForFrameTriggerReady(timeout_ms, pylon.TimeoutHandling_ThrowException)
            camera.ExecuteSoftwareTrigger()
            result = camera.RetrieveResult(timeout_ms, pylon.TimeoutHandling_ThrowException)
        except genicam.TimeoutException:
            camera.StopGrabbing()  # a late frame must not be taken for the next one
            raise HardwareError(f"{self.name}: no frame within {timeout_s:g} s (frame timeout)") from None
        except genicam.GenericException as error:
            if camera.IsCameraDeviceRemoved():
                raise HardwareError(f"{self.name}: disconnected") from None
            raise HardwareError(f"{self.name}: grab failed: {_first_line(error)}") from None
        try:
            if not result.GrabSucceeded():
                if camera.IsCameraDeviceRemoved():
                    raise HardwareError(f"{self.name}: disconnected")
                raise HardwareError(f"{self.name}: grab failed: {result.GetErrorDescription()}")
            rows, cols = result.GetHeight(), result.GetWidth()
            samples = np.frombuffer(result.GetBuffer(), np.uint16)
            channels = 3 if self.pixel_format.startswith("RGB") else 1
            # pypylon's Array does not decode RGB16Packed; the buffer is row-major samples.
            return samples[:rows * cols * channels].reshape(rows, cols * channels).copy()
        finally:
            result.Release()

    def _guarded(self, action, what: str):
        _, genicam = _pylon()
        try:
            return action()
        except genicam.GenericException as error:
            if self.camera is not None and self.camera.IsCameraDeviceRemoved():
                raise HardwareError(f"{self.name}: disconnected") from None
            raise HardwareError(f"{self.name}: {what}: {_first_line(error)}") from None


def _first_line(error: Exception) -> str:
    return str(error).split(" : ")[0].splitlines()[0] if str(error) else type(error).__name__


def make_pylon_camera(serial: str = "", pixel_format: str = "", frame_timeout: str = "5", feed: str = "",
                      **rig_options: str) -> PylonCamera:
    """The factory behind ``--camera pylon``; ``rig_options`` only with ``feed=simulated``."""
    if feed not in ("", "simulated"):
        raise HardwareError(f"pylon camera: feed must be 'simulated' or absent, got {feed!r}")
    if rig_options and not feed:
        raise HardwareError(f"pylon camera: unknown options {', '.join(sorted(rig_options))} "
                            "(serial, pixel_format, frame_timeout, feed)")
    source = None
    if feed:
        from .simulated_presets import simulated_camera

        source = SimulatedFeed(simulated_camera(**rig_options))
    return PylonCamera(serial, pixel_format, frame_timeout, source)


PLUGIN = HardwarePlugin(
    name="pylon",
    cameras={"pylon": make_pylon_camera},
    description="Basler cameras through pypylon (options: serial, pixel_format, frame_timeout, feed)",
    unavailable="" if importlib.util.find_spec("pypylon") else INSTALL_HINT,
)
