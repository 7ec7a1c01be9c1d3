"""A virtual projector-camera rig over a simulated scene, and its devices: the ``simulated``
hardware backend (the plugin that makes rigs from a user's options: :mod:`.simulated_presets`).

The projector shows patterns on the scene's grid (one projector pixel per grid point). The scene
radiance under a pattern is the sum of the lit points' simulated responses (the simulator's
transport windows). The camera samples that radiance through a :class:`CameraSampling` (scale,
rotation, offset: camera pixel centre -> projector position) and records it like a machine-vision
sensor: electrons = radiance x gain x exposure with Poisson shot noise, Gaussian read noise, a
black level, 12-bit quantisation and saturation. Noise is seeded by the pattern, the exposure and
how many frames of that exposure were taken since the pattern was shown, so the same sequence of
shows and captures repeats exactly (a resumed scan equals an uninterrupted one) while repeated
frames of one pattern carry independent noise (a dark frame's average measures the read noise).

The scene ``colorchecker`` is a flat ColorChecker chart (Lambertian, no subsurface light) seen by
a camera whose RGB -> XYZ matrix is :data:`CAMERA_RGB_TO_XYZ`: the colour step's test target.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .hardware import HardwareError

if TYPE_CHECKING:
    from .simulated_presets import RigRequest


@dataclass(frozen=True)
class CameraSampling:
    """Where camera pixels look: projector position (y, x) of camera pixel centre (r + 0.5, c + 0.5)
    is ``R(rotation) @ ((r + 0.5, c + 0.5) / scale) + offset``; projector pixel [y, x] covers
    [y, y + 1) x [x, x + 1). ``margin`` extra camera pixels on each side see beyond the projector."""

    scale: float = 2.0
    rotation_deg: float = 1.5
    offset: tuple[float, float] = (-0.7, 0.4)
    margin: int = 2

    def camera_shape(self, projector_size: tuple[int, int]) -> tuple[int, int]:
        return (int(math.ceil(projector_size[0] * self.scale)) + 2 * self.margin,
                int(math.ceil(projector_size[1] * self.scale)) + 2 * self.margin)

    def projector_position(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projector (y, x) of the centres of camera pixels (rows, cols)."""
        v = (np.asarray(rows, np.float64) + 0.5 - self.margin) / self.scale
        u = (np.asarray(cols, np.float64) + 0.5 - self.margin) / self.scale
        angle = math.radians(self.rotation_deg)
        y = math.cos(angle) * v + math.sin(angle) * u + self.offset[0]
        x = -math.sin(angle) * v + math.cos(angle) * u + self.offset[1]
        return y, x


@dataclass(frozen=True)
class SensorModel:
    """Camera noise and range: ``gain`` electrons per unit radiance per second."""

    gain: float = 4.0e6
    read_noise: float = 2.0
    black_level: float = 64.0
    bits: int = 12
    exposure_range: tuple[float, float] = (1e-4, 2.0)

    @property
    def saturation_level(self) -> float:
        return float(2**self.bits - 1)


class SimulatedRig:
    """A projector and a camera sharing one scene; ``windows`` as in ``Transport.windows``.

    ``fail_after``: :attr:`camera` raises HardwareError after that many captures (to rehearse a
    camera that stops answering). ``options``: the ``simulated`` plugin's options it was made
    from (``scene``, ``size``, ``photons``, ``seed``, normalised: :func:`key_options`), which tell
    rigs apart (:func:`pair_problem`); empty for a rig made otherwise.
    """

    def __init__(self, windows: np.ndarray, sampling: CameraSampling = CameraSampling(),
                 sensor: SensorModel = SensorModel(), seed: int = 0, fail_after: int | None = None,
                 settle_time: float = 0.0, options: dict[str, str] | None = None):
        self.windows = np.asarray(windows, np.float32)
        self.size = self.windows.shape[:2]
        self.radius = (self.windows.shape[2] - 1) // 2
        self.sampling = sampling
        self.sensor = sensor
        self.seed = seed
        self.options = dict(options or {})
        self.pattern = np.zeros(self.size, np.float32)
        self.repeats: dict[float, int] = {}
        """Frames taken per exposure since the pattern was shown (a noise seed)."""
        self.projector = SimulatedProjector(self, settle_time)
        self.camera = SimulatedCamera(self, fail_after)
        rows, cols = np.mgrid[:sampling.camera_shape(self.size)[0], :sampling.camera_shape(self.size)[1]]
        y, x = sampling.projector_position(rows, cols)
        self.seen_y, self.seen_x = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
        self.sees_scene = (self.seen_y >= 0) & (self.seen_y < self.size[0]) & (self.seen_x >= 0) & (self.seen_x < self.size[1])

    def scene_radiance(self, pattern: np.ndarray) -> np.ndarray:
        """(H, W, 3) radiance on the grid under ``pattern`` (H, W) in [0, 1]."""
        height, width = self.size
        radiance = np.zeros((height, width, 3), np.float64)
        weighted = self.windows * pattern[:, :, None, None, None]
        r = self.radius
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                # Light of lit point q = (y, x) leaving at q + (dy, dx).
                ys, ye = max(0, -dy), min(height, height - dy)
                xs, xe = max(0, -dx), min(width, width - dx)
                if ys < ye and xs < xe:
                    radiance[ys + dy:ye + dy, xs + dx:xe + dx] += weighted[ys:ye, xs:xe, dy + r, dx + r]
        return radiance

    def capture(self, exposure: float) -> np.ndarray:
        low, high = self.sensor.exposure_range
        if not low <= exposure <= high:
            raise HardwareError(f"simulated camera: exposure {exposure:g} s outside {low:g}..{high:g} s")
        radiance = self.scene_radiance(self.pattern)
        seen = np.zeros((*self.seen_y.shape, 3))
        seen[self.sees_scene] = radiance[self.seen_y[self.sees_scene], self.seen_x[self.sees_scene]]
        key = zlib.crc32(self.pattern.tobytes())
        repeat = self.repeats.get(exposure, 0)
        self.repeats[exposure] = repeat + 1
        rng = np.random.default_rng([self.seed, key, int(round(exposure * 1e9))] + ([repeat] if repeat else []))
        # A Monte Carlo estimate of the transport may dip below zero where little light returns:
        # no camera sees negative light.
        electrons = rng.poisson(np.maximum(seen, 0.0) * self.sensor.gain * exposure).astype(np.float64)
        raw = electrons + rng.normal(0.0, self.sensor.read_noise, seen.shape) + self.sensor.black_level
        return np.clip(np.round(raw), 0, self.sensor.saturation_level).astype(np.float32)


class _RigDevice:
    """A device of a rig, given the rig or a request for it, made at first need
    (:class:`.simulated_presets.RigRequest`: its ``options``, ``sensor`` and ``make()``)."""

    def __init__(self, rig: SimulatedRig | RigRequest):
        self._rig = rig

    @property
    def rig(self) -> SimulatedRig:
        self.open()
        return self._rig

    @property
    def sensor(self) -> SensorModel:
        """The rig's sensor, known before the rig is made."""
        return self._rig.sensor

    @property
    def simulated_scene(self) -> dict[str, str]:
        """The options of the rig whose scene it sees or lights (empty for a rig made otherwise
        than by :func:`.simulated_presets.preset_rig`), known before the rig is made."""
        return self._rig.options

    def open(self) -> None:
        """Make the rig (the simulator runs) when the factory only asked for it."""
        if not isinstance(self._rig, SimulatedRig):
            self._rig = self._rig.make()

    def close(self) -> None:
        pass


class SimulatedCamera(_RigDevice):
    """A camera of the rig (see :class:`SimulatedRig`): it sees what the rig's projector shows.
    ``fail_after``: it raises HardwareError after that many captures (None: never)."""

    def __init__(self, rig: SimulatedRig | RigRequest, fail_after: int | None = None):
        super().__init__(rig)
        self.fail_after = fail_after
        self.captures = 0

    def pair_problem(self, projector) -> str | None:
        """Why this camera cannot film what ``projector`` shows (:func:`pair_problem`), or None."""
        return pair_problem(self, projector)

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return (*self.rig.seen_y.shape, 3)

    @property
    def exposure_range(self) -> tuple[float, float]:
        return self.sensor.exposure_range

    @property
    def saturation_level(self) -> float:
        return self.sensor.saturation_level

    @property
    def black_level(self) -> float:
        return self.sensor.black_level

    def properties(self) -> dict[str, str]:
        """Its description for the dataset's notes; a preset rig's options with it (``rig``), so
        that a scan resumed on another rig is told apart (:func:`.workflow.check_same_camera`)."""
        sampling = self.rig.sampling
        rig = {"rig": describe_rig(self.rig.options)} if self.rig.options else {}
        return {"backend": "simulated", "bits": str(self.rig.sensor.bits),
                "sampling": f"scale {sampling.scale:g}, rotation {sampling.rotation_deg:g} deg, "
                            f"offset {sampling.offset[0]:g},{sampling.offset[1]:g}", **rig}

    def capture(self, exposure: float) -> np.ndarray:
        if self.fail_after is not None and self.captures >= self.fail_after:
            raise HardwareError("simulated camera stopped answering (fail_after reached)")
        self.captures += 1
        return self.rig.capture(exposure)


class SimulatedProjector(_RigDevice):
    """The rig's projector: one projector pixel per grid point of the scene. ``fail_after``: the
    option as it was given to the projector (:func:`.simulated_presets.simulated_projector`), which it
    does not use."""

    def __init__(self, rig: SimulatedRig | RigRequest, settle_time: float, fail_after: int | None = None):
        super().__init__(rig)
        self.settle_time = settle_time
        self.fail_after = fail_after

    def pair_problem(self, camera) -> str | None:
        """Why ``camera`` cannot film what this projector shows (:func:`pair_problem`), or None."""
        return pair_problem(camera, self)

    @property
    def size(self) -> tuple[int, int]:
        return self.rig.size

    def show(self, pattern: np.ndarray) -> None:
        pattern = np.asarray(pattern, np.float32)
        if pattern.shape != self.rig.size:
            raise HardwareError(f"simulated projector: pattern {pattern.shape} is not {self.rig.size}")
        self.rig.pattern = np.clip(pattern, 0, 1)
        self.rig.repeats = {}

    def show_black(self) -> None:
        self.show(np.zeros(self.rig.size, np.float32))

    def show_white(self) -> None:
        self.show(np.ones(self.rig.size, np.float32))


def pair_problem(camera, projector) -> str | None:
    """Why ``camera`` cannot film what ``projector`` shows, when either is simulated, or None.

    A simulated device (one with a ``simulated_scene``: this module's, a pylon camera with
    ``feed=simulated``) sees or lights only its rig's scene, so both must be of one rig: made from
    the same options, which are compared before the rig is made. Two rigs (a camera given
    ``seed=1``, its projector not), or a simulated device with a real one, would scan a dark
    frame's noise into a dataset. ``fail_after`` is the camera's: given to the projector alone, it
    would rehearse nothing."""
    seen = getattr(camera, "simulated_scene", None)
    lit = getattr(projector, "simulated_scene", None)
    if seen is None and lit is None:
        return None
    if seen is None:
        return ("the simulated projector lights only its simulated scene, which a real camera does not see: "
                "use a simulated camera with it")
    if lit is None:
        return "the simulated camera sees only the simulated projector's scene: use the simulated projector with it"
    differ = [f"{key}: camera {seen.get(key, '-')}, projector {lit.get(key, '-')}"
              for key in sorted(set(seen) | set(lit)) if seen.get(key) != lit.get(key)]
    if differ:
        return (f"the camera and the projector were given different simulated rigs ({'; '.join(differ)}): give "
                "scene, size, photons and seed once, as options for both devices")
    given = getattr(projector, "fail_after", None)
    if given is not None and getattr(camera, "fail_after", None) != given:
        return (f"fail_after={given} was given to the projector alone: it is the simulated camera's option; "
                "give it to the camera, or as an option for both devices")
    return None


CAMERA_RGB_TO_XYZ = np.array([[0.7977, 0.1352, 0.0313], [0.2880, 0.7119, 0.0001], [0.0, 0.0, 0.8249]])
"""The simulated camera's RGB -> XYZ (ProPhoto RGB's primaries: every ColorChecker patch has
positive camera RGB), for the ``colorchecker`` scene."""


def colorchecker_windows(height: int, width: int) -> np.ndarray:
    """Transport windows (H, W, 3, 3, 3) of a flat ColorChecker filling the grid: 4 x 6 patches,
    each the central 70 % of its cell, camera RGB = inverse(CAMERA_RGB_TO_XYZ) @ the patch's XYZ;
    the gaps between patches reflect 0.01. Light stays where it enters (the centre tap)."""
    from .calibration import CHECKER_COLUMNS, CHECKER_ROWS, colorchecker_xyz

    rgb = np.linalg.solve(CAMERA_RGB_TO_XYZ, colorchecker_xyz().T).T
    v = (np.arange(height) + 0.5) / height * CHECKER_ROWS
    u = (np.arange(width) + 0.5) / width * CHECKER_COLUMNS
    inside = (np.abs(v % 1 - 0.5) < 0.35)[:, None] & (np.abs(u % 1 - 0.5) < 0.35)[None, :]
    patch = v.astype(int)[:, None] * CHECKER_COLUMNS + u.astype(int)[None, :]
    windows = np.zeros((height, width, 3, 3, 3), np.float32)
    windows[:, :, 1, 1] = np.where(inside[..., None], rgb[patch], 0.01)
    return windows


def key_options(key: tuple) -> dict[str, str]:
    """A rig key's options (:func:`.simulated_presets.rig_key`), normalised, as
    :attr:`SimulatedRig.options` holds them."""
    scene, size, photons, seed = key
    return {"scene": scene, "size": f"{size[0]}x{size[1]}", "photons": str(photons), "seed": str(seed)}


def describe_rig(options: dict[str, str]) -> str:
    """A preset rig's options as the notes hold them: ``scene red-bead; size 24x24; ...``."""
    return "; ".join(f"{key} {value}" for key, value in options.items())
