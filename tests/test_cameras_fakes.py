"""The genicam (harvesters) and spinnaker (PySpin) plugins, driven through fakes of their SDKs that
hold one SFNC camera: the same features, ranges and frames as the SDK would give."""

import contextlib
import importlib.util
from types import SimpleNamespace

import numpy as np
import pytest
from ringlight.core.capture.genicam_camera import GenICamCamera
from ringlight.core.capture.hardware import HardwareError, discover_plugins
from ringlight.core.capture.machine_vision import decode_frame
from ringlight.core.capture.spinnaker_camera import SpinnakerCamera

BLACK = 32.0
RATE = np.arange(12 * 16, dtype=np.float64).reshape(12, 16) * 1000.0  # counts per second


class FakeDevice:
    """One SFNC camera: features as {name: [value, range]} and frames of RATE x exposure + black."""

    def __init__(self, serial="SN42"):
        self.serial = serial
        self.features = {
            "PixelFormat": ["Mono8", ("Mono8", "Mono12", "BayerRG12")], "ExposureAuto": ["Continuous", ("Off", "Continuous")],
            "GainAuto": ["Continuous", ("Off", "Continuous")], "Gain": [6.0, (0.0, 24.0)],
            "ExposureTime": [1000.0, (10.0, 3.0e7)], "BlackLevel": [BLACK, (0.0, 255.0)], "Width": [16, (1, 16)],
            "Height": [12, (1, 12)], "TriggerMode": ["Off", ("Off", "On")], "TriggerSource": ["Line0", ("Line0", "Software")],
            "TriggerSelector": ["FrameStart", ("FrameStart",)],
        }
        self.triggers = 0
        self.fail = None  # "timeout" or "unplugged"

    def frame(self) -> np.ndarray:
        assert self.features["TriggerMode"][0] == "On" and self.features["TriggerSource"][0] == "Software"
        seconds = self.features["ExposureTime"][0] * 1e-6
        return np.minimum(np.round(RATE * seconds + BLACK), 4095).astype(np.uint16)


# --- harvesters ---------------------------------------------------------------------------


class HarvesterTimeout(Exception):
    pass


class HarvesterNode:
    def __init__(self, device, name):
        self.device, self.name = device, name
        choices = device.features[name][1]
        if isinstance(choices[0], str):
            self.symbolics = choices
        else:
            self.min, self.max = choices

    @property
    def value(self):
        return self.device.features[self.name][0]

    @value.setter
    def value(self, value):
        choices = self.device.features[self.name][1]
        if (value not in choices) if isinstance(choices[0], str) else not choices[0] <= value <= choices[1]:
            raise ValueError(f"{value} out of range")
        self.device.features[self.name][0] = value


class HarvesterNodeMap:
    def __init__(self, device):
        self._device = device

    def __getattr__(self, name):
        if name == "TriggerSoftware":
            return SimpleNamespace(execute=lambda: setattr(self._device, "triggers", self._device.triggers + 1))
        if name not in self._device.features:
            raise AttributeError(name)
        return HarvesterNode(self._device, name)


class FakeHarvester:
    devices = [FakeDevice()]

    def __init__(self):
        self.files, self.device_info_list, self.acquiring = [], [], False

    def add_file(self, path):
        self.files.append(path)

    def update(self):
        self.device_info_list = [SimpleNamespace(serial_number=d.serial, model="Fake", vendor="Acme") for d in self.devices]

    def create(self, index):
        device = self.devices[index]
        harvester = self

        class Acquirer:
            remote_device = SimpleNamespace(node_map=HarvesterNodeMap(device))

            def is_acquiring(self):
                return harvester.acquiring

            def start(self):
                harvester.acquiring = True

            def stop(self):
                harvester.acquiring = False

            def destroy(self):
                harvester.destroyed = True

            @contextlib.contextmanager
            def fetch(self, timeout):
                if device.fail == "timeout":
                    raise HarvesterTimeout()
                if device.fail == "unplugged":
                    raise OSError("GenTL: device lost")
                data = device.frame().ravel()
                component = SimpleNamespace(data=data, width=16, height=12)
                yield SimpleNamespace(payload=SimpleNamespace(components=[component]))
        return Acquirer()

    def reset(self):
        self.device_info_list = []


@pytest.fixture
def cti(tmp_path):
    path = tmp_path / "producer.cti"
    path.write_bytes(b"")
    FakeHarvester.devices = [FakeDevice("SN41"), FakeDevice("SN42")]
    return str(path)


def test_genicam_camera_is_opened_by_serial_and_set_up_through_sfnc_features(cti):
    camera = GenICamCamera(cti, "SN42", sdk=(FakeHarvester, HarvesterTimeout))
    camera.open()
    device = FakeHarvester.devices[1]
    try:
        # The first supported format, automatic exposure and gain off, gain at 0 dB, black level read.
        assert {name: device.features[name][0] for name in ("PixelFormat", "ExposureAuto", "GainAuto", "Gain")} == {
            "PixelFormat": "Mono12", "ExposureAuto": "Off", "GainAuto": "Off", "Gain": 0.0}
        assert (camera.black_level, camera.saturation_level, camera.frame_shape) == (BLACK, 4095.0, (12, 16))
        assert camera.exposure_range == pytest.approx((1e-5, 30.0))
        frame = camera.capture(0.002)
        assert device.features["ExposureTime"][0] == pytest.approx(2000.0) and device.triggers == 1
        np.testing.assert_array_equal(frame, np.round(RATE * 0.002 + BLACK))  # counts x seconds + black
        assert camera.properties() == {"backend": "genicam producer.cti", "model": "Acme Fake", "serial": "SN42",
                                       "pixel format": "Mono12", "bits": "12", "gain": "0 dB", "black level": "32"}
    finally:
        camera.close()
    with pytest.raises(HardwareError, match="no camera with serial 'SN9'; found SN41, SN42"):
        GenICamCamera(cti, "SN9", sdk=(FakeHarvester, HarvesterTimeout)).open()


@pytest.mark.parametrize("failure, message", [("timeout", r"no frame within 5.01 s \(frame timeout\)"),
                                               ("unplugged", "disconnected or failed: OSError: GenTL: device lost")])
def test_genicam_timeouts_and_lost_devices_are_hardware_errors(cti, failure, message):
    camera = GenICamCamera(cti, "SN41", sdk=(FakeHarvester, HarvesterTimeout))
    camera.open()
    try:
        FakeHarvester.devices[0].fail = failure
        with pytest.raises(HardwareError, match=f"genicam camera SN41: {message}"):
            camera.capture(0.01)
    finally:
        camera.close()


def test_genicam_refuses_a_missing_producer_and_names_what_to_install(tmp_path):
    with pytest.raises(HardwareError, match="no GenTL producer at .*give its .cti path"):
        GenICamCamera(str(tmp_path / "none.cti"), sdk=(FakeHarvester, HarvesterTimeout)).open()
    if importlib.util.find_spec("harvesters") is None:
        reasons = dict(discover_plugins().failures)
        assert reasons["genicam"].startswith("harvesters is not installed: pip install 'ringlight[genicam]'")


# --- PySpin --------------------------------------------------------------------------------


class SpinnakerException(Exception):
    def __init__(self, message, errorcode):
        super().__init__(message)
        self.errorcode = errorcode


def fake_pyspin(devices):
    """A PySpin module with the calls the plugin makes, over ``devices``."""
    spin = SimpleNamespace(intfIFloat=1, intfIInteger=2, intfIEnumeration=3, intfIString=4, intfICommand=5,
                           SPINNAKER_ERR_TIMEOUT=-1011, SpinnakerException=SpinnakerException)
    spin.IsAvailable = lambda node: node is not None
    spin.CEnumEntryPtr = lambda entry: entry

    class Node:
        def __init__(self, device, name):
            self.device, self.name = device, name

        def GetPrincipalInterfaceType(self):
            if self.name == "TriggerSoftware":
                return spin.intfICommand
            return spin.intfIEnumeration if isinstance(self.device.features[self.name][1][0], str) else spin.intfIFloat

    class Number(Node):
        def GetValue(self):
            return self.device.features[self.name][0]

        def SetValue(self, value):
            low, high = self.device.features[self.name][1]
            if not low <= value <= high:
                raise SpinnakerException(f"{self.name} {value} out of range", -1002)
            self.device.features[self.name][0] = value

        def GetMin(self):
            return self.device.features[self.name][1][0]

        def GetMax(self):
            return self.device.features[self.name][1][1]

    class Enumeration(Node):
        def GetEntries(self):
            return [SimpleNamespace(GetSymbolic=lambda s=s: s, GetValue=lambda i=i: i)
                    for i, s in enumerate(self.device.features[self.name][1])]

        def GetEntryByName(self, name):
            return next((entry for entry in self.GetEntries() if entry.GetSymbolic() == name), None)

        def GetCurrentEntry(self):
            return self.GetEntryByName(self.device.features[self.name][0])

        def SetIntValue(self, index):
            if self.name == "TriggerSource" and self.device.features["TriggerMode"][0] == "On":
                raise SpinnakerException("TriggerSource is read-only while TriggerMode is On", -1006)
            self.device.features[self.name][0] = self.device.features[self.name][1][index]

    class Command(Node):
        def Execute(self):
            self.device.triggers += 1

    spin.CFloatPtr = spin.CIntegerPtr = spin.CStringPtr = lambda node: Number(node.device, node.name)
    spin.CEnumerationPtr = lambda node: Enumeration(node.device, node.name)
    spin.CCommandPtr = lambda node: Command(node.device, node.name)

    class Camera:
        def __init__(self, device):
            self.device, self.streaming, self.initialised = device, False, False
            info = SimpleNamespace(GetValue=lambda: device.serial)
            self.TLDevice = SimpleNamespace(DeviceSerialNumber=info,
                                            DeviceModelName=SimpleNamespace(GetValue=lambda: "Grasshopper3 GS3-U3-32S4M"))

        def GetNodeMap(self):
            device = self.device
            return SimpleNamespace(GetNode=lambda name: Node(device, name)
                                   if name in device.features or name == "TriggerSoftware" else None)

        def Init(self):
            self.initialised = True

        def IsInitialized(self):
            return self.initialised

        def DeInit(self):
            self.initialised = False

        def IsStreaming(self):
            return self.streaming

        def BeginAcquisition(self):
            self.streaming = True

        def EndAcquisition(self):
            self.streaming = False

        def IsValid(self):
            return self.device.fail != "unplugged"

        def GetNextImage(self, timeout_ms):
            if self.device.fail == "timeout":
                raise SpinnakerException("Failed waiting for EventData on NEW_BUFFER_DATA event.", -1011)
            if self.device.fail == "unplugged":
                raise SpinnakerException("Camera is not valid", -1004)
            frame = self.device.frame()
            return SimpleNamespace(IsIncomplete=lambda: False, GetNDArray=lambda: frame, GetHeight=lambda: 12,
                                   Release=lambda: None)

    cameras = [Camera(device) for device in devices]
    camera_list = SimpleNamespace(GetSize=lambda: len(cameras), GetByIndex=lambda i: cameras[i], Clear=lambda: None)
    system = SimpleNamespace(GetCameras=lambda: camera_list, ReleaseInstance=lambda: None,
                             GetLibraryVersion=lambda: SimpleNamespace(major=4))
    spin.System = SimpleNamespace(GetInstance=lambda: system)
    return spin


def test_spinnaker_camera_sets_trigger_gain_and_exposure_and_reads_frames():
    device = FakeDevice("17171717")
    camera = SpinnakerCamera("17171717", "BayerRG12", sdk=fake_pyspin([FakeDevice("1"), device]))
    camera.open()
    try:
        assert [device.features[name][0] for name in ("TriggerMode", "TriggerSource", "Gain", "ExposureAuto")] == [
            "On", "Software", 0.0, "Off"]
        frame = camera.capture(0.5)
        assert device.features["ExposureTime"][0] == pytest.approx(5e5) and device.triggers == 1
        raw = np.minimum(np.round(RATE * 0.5 + BLACK), 4095).astype(np.uint16)
        np.testing.assert_array_equal(frame, decode_frame(raw, "BayerRG12"))  # demosaiced to (12, 16, 3)
        assert frame.shape == camera.frame_shape == (12, 16, 3)
        assert camera.properties()["model"] == "Grasshopper3 GS3-U3-32S4M"
        with pytest.raises(HardwareError, match="exposure 40 s outside 1e-05..30 s"):
            camera.capture(40.0)
        device.fail = "timeout"
        with pytest.raises(HardwareError, match="spinnaker camera 17171717: no frame within 5.5 s"):
            camera.capture(0.5)
        device.fail = "unplugged"
        with pytest.raises(HardwareError, match="spinnaker camera 17171717: disconnected"):
            camera.capture(0.5)
    finally:
        camera.close()
    assert not camera.is_open and camera.camera is None


def test_spinnaker_refuses_an_unknown_serial_and_is_listed_with_its_reason_without_pyspin():
    with pytest.raises(HardwareError, match="no camera with serial '9'; found 1"):
        SpinnakerCamera("9", sdk=fake_pyspin([FakeDevice("1")])).open()
    if importlib.util.find_spec("PySpin") is None:
        reason = dict(discover_plugins().failures)["spinnaker"]
        assert reason.startswith("PySpin is not installed: install FLIR's Spinnaker SDK") and "\n" not in reason
