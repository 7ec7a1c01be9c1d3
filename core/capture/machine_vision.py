"""What the machine-vision camera plugins (pylon, genicam, spinnaker) share.

These cameras speak the GenICam Standard Features Naming Convention (SFNC): ``PixelFormat``,
``ExposureTime`` (microseconds), ``Gain`` (dB), ``BlackLevel`` (counts of the pixel format).
:class:`SfncCamera` implements the :class:`~.hardware.Camera` protocol over four small
SDK-specific methods, so that each plugin is only the glue to its SDK:

- exposure in seconds, refused outside the camera's range;
- automatic exposure and gain off, gain fixed at 0 dB (the lowest the camera allows) and recorded;
- the black level read from the camera, the saturation level from the pixel format's bit depth;
- Bayer formats demosaiced with OpenCV into (rows, cols, 3), RGB formats kept, mono as (rows, cols).

Frames are float32 raw counts of the pixel format (black level not subtracted).
"""

from __future__ import annotations

import math
import re

import cv2
import numpy as np

from .hardware import HardwareError, OptionError

SUPPORTED_FORMATS = ("Mono12", "Mono16", "BayerRG12", "BayerGR12", "BayerGB12", "BayerBG12",
                     "BayerRG16", "BayerGR16", "BayerGB16", "BayerBG16", "RGB16", "RGB16Packed")
"""Linear formats of at least 12 bits, in the order a camera's first supported one is chosen."""
MAX_FRAME_TIMEOUT = 3600.0
"""Longest ``frame_timeout`` in seconds: an hour beyond the exposure. pylon and Spinnaker wait in
integer milliseconds, which ``nan`` or ``inf`` made fail at the first capture, after the projector
had begun; a wait of zero or less never sees a frame."""

# OpenCV names Bayer patterns by the second row's first two pixels: a sensor whose first row
# starts R G (SFNC "BayerRG") is OpenCV's "BG" pattern.
_OPENCV_BAYER = {"RG": cv2.COLOR_BayerBG2RGB, "GR": cv2.COLOR_BayerGB2RGB,
                 "GB": cv2.COLOR_BayerGR2RGB, "BG": cv2.COLOR_BayerRG2RGB}


def format_bits(pixel_format: str) -> int:
    """Bits per sample of an SFNC pixel format name, e.g. 12 for ``"BayerRG12"``."""
    match = re.search(r"(\d+)(?:p|Packed)?$", pixel_format)
    if match is None or pixel_format not in SUPPORTED_FORMATS:
        raise HardwareError(f"pixel format {pixel_format!r} is not supported; use one of {', '.join(SUPPORTED_FORMATS)}")
    return int(match.group(1))


def is_colour_format(pixel_format: str) -> bool:
    return pixel_format.startswith(("Bayer", "RGB"))


def decode_frame(raw: np.ndarray, pixel_format: str) -> np.ndarray:
    """Raw uint16 samples -> float32 frame.

    ``raw``: (rows, cols) for mono and Bayer formats, (rows, cols, 3) or (rows, cols * 3) for RGB.
    Returns (rows, cols) for mono, (rows, cols, 3) RGB for the others; Bayer is demosaiced by
    OpenCV's bilinear interpolation, which keeps every measured sample.
    """
    raw = np.asarray(raw)
    if pixel_format.startswith("Bayer"):
        return cv2.cvtColor(np.ascontiguousarray(raw, np.uint16), _OPENCV_BAYER[pixel_format[5:7]]).astype(np.float32)
    if pixel_format.startswith("RGB"):
        return raw.reshape(raw.shape[0], -1, 3).astype(np.float32)
    return raw.astype(np.float32)


class SfncCamera:
    """A :class:`~.hardware.Camera` over an SFNC node map; subclasses connect it to an SDK.

    Subclasses implement ``_connect()`` (open the device, return its description),
    ``_disconnect()``, ``_feature(name)`` (get), ``_set_feature(name, value)``,
    ``_feature_range(name)`` ((min, max) of a number, the tuple of choices of an enumeration,
    None where the camera lacks the feature) and
    ``_grab(timeout_s)`` (one triggered frame as a uint16 array, HardwareError on failure).
    ``name`` labels messages, e.g. ``"pylon camera 0815-0000"``.
    """

    name = "camera"

    def __init__(self, pixel_format: str = "", frame_timeout: str = "5"):
        if pixel_format:
            format_bits(pixel_format)
        self.frame_timeout = self._parse_frame_timeout(frame_timeout)
        self.pixel_format = pixel_format
        self.description: dict[str, str] = {}
        self.is_open = False
        self._exposure_range = (0.0, 0.0)
        self._black = 0.0
        self._gain_db = 0.0
        self._shape: tuple[int, ...] = (0, 0)

    def _parse_frame_timeout(self, value: str) -> float:
        """Option ``frame_timeout`` (a string, as typed) in seconds, > 0 and at most MAX_FRAME_TIMEOUT."""
        try:
            seconds = float(value)
        except ValueError:
            seconds = math.nan
        if not 0 < seconds <= MAX_FRAME_TIMEOUT:  # also refuses nan
            raise OptionError(self.name, "frame_timeout", value,
                              f"must be a number of seconds > 0 and at most {MAX_FRAME_TIMEOUT:g}")
        return seconds

    def open(self) -> None:
        self.description = self._connect()
        self.is_open = True
        try:
            self._configure()
        except HardwareError:
            self.close()
            raise

    def _configure(self) -> None:
        offered = self._feature_range("PixelFormat") or ()
        chosen = self.pixel_format or next((f for f in SUPPORTED_FORMATS if f in offered), "")
        if chosen not in offered:
            raise HardwareError(f"{self.name}: pixel format {chosen or 'of 12 or 16 bits'} not offered; "
                                f"it offers {', '.join(offered) or 'none'}")
        self._set_feature("PixelFormat", chosen)
        self.pixel_format = chosen
        for automatic in ("ExposureAuto", "GainAuto"):
            if self._feature_range(automatic) is not None:
                self._set_feature(automatic, "Off")
        gain = self._feature_range("Gain")
        if gain is not None:
            # 0 dB: the sensor's native gain, the widest range and the lowest noise per count.
            self._set_feature("Gain", max(0.0, gain[0]))
            self._gain_db = float(self._feature("Gain"))
        low, high = self._feature_range("ExposureTime") or (None, None)
        if low is None:
            raise HardwareError(f"{self.name}: has no ExposureTime feature; exposure must be under software control")
        self._exposure_range = (low * 1e-6, high * 1e-6)
        self._black = float(self._feature("BlackLevel")) if self._feature_range("BlackLevel") is not None else 0.0
        self._shape = (int(self._feature("Height")), int(self._feature("Width")))
        if is_colour_format(chosen):
            self._shape = (*self._shape, 3)

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self._disconnect()

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return self._shape

    @property
    def exposure_range(self) -> tuple[float, float]:
        return self._exposure_range

    @property
    def saturation_level(self) -> float:
        return float(2 ** format_bits(self.pixel_format) - 1)

    @property
    def black_level(self) -> float:
        return self._black

    def properties(self) -> dict[str, str]:
        return {**self.description, "pixel format": self.pixel_format,
                "bits": str(format_bits(self.pixel_format)), "gain": f"{self._gain_db:g} dB",
                "black level": f"{self._black:g}"}

    def capture(self, exposure: float) -> np.ndarray:
        """One frame exposed for ``exposure`` seconds; HardwareError when the camera is closed,
        refuses the exposure, delivers no frame within the exposure plus ``frame_timeout`` or
        was disconnected."""
        if not self.is_open:
            raise HardwareError(f"{self.name}: not open")
        low, high = self._exposure_range
        if not low <= exposure <= high:
            raise HardwareError(f"{self.name}: exposure {exposure:g} s outside {low:g}..{high:g} s")
        self._set_feature("ExposureTime", exposure * 1e6)
        return decode_frame(self._grab(exposure + self.frame_timeout), self.pixel_format)

    def _connect(self) -> dict[str, str]:
        raise NotImplementedError

    def _disconnect(self) -> None:
        raise NotImplementedError

    def _feature(self, name: str):
        raise NotImplementedError

    def _set_feature(self, name: str, value) -> None:
        raise NotImplementedError

    def _feature_range(self, name: str):
        raise NotImplementedError

    def _grab(self, timeout_s: float) -> np.ndarray:
        raise NotImplementedError
