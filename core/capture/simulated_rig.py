"""A virtual projector-camera rig over a simulated scene: the ``simulated`` hardware backend.

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
import os
import re
import threading
import weakref
import zlib
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .hardware import HardwareError, HardwarePlugin, OptionError, ProgressCallback


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


class RigRequest:
    """A preset rig asked for by its options (:func:`rig_key`) and made when a device first needs
    it (:func:`preset_rig`), with ``progress``: the simulated devices' factories validate their
    options and compare them (:func:`pair_problem`) before anything is simulated."""

    sensor = SensorModel()
    """Every preset rig's sensor (:func:`_make_rig`), known before the rig is made."""

    def __init__(self, key: tuple, progress: ProgressCallback | None = None):
        self.key = key
        self.progress = progress

    @property
    def options(self) -> dict[str, str]:
        """The rig's options, normalised (``seed=01`` is seed 1)."""
        return key_options(self.key)

    def make(self) -> SimulatedRig:
        return _rig_for(self.key, self.progress)


class _RigDevice:
    """A device of a rig, given the rig or a :class:`RigRequest` for it (made at first need)."""

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
        than by :func:`preset_rig`), known before the rig is made."""
        return self._rig.options

    def open(self) -> None:
        """Make the rig (the simulator runs) when the factory only asked for it."""
        if isinstance(self._rig, RigRequest):
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
    option as it was given to the projector (:func:`simulated_projector`), which it does not use."""

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


RIG = "simulated rig"
"""How messages name the rig."""
MIN_SIDE = 2
"""Fewest projector pixels along each side: OpenCV's Gray code decoding crashed the process (a
segmentation fault) for a projector one pixel high or wide."""
MAX_SIDE = 1024
"""Most projector pixels along each side: one capture of a 1024 x 1024 ``colorchecker`` rig takes
about 5 s (a preset's simulation is refused well below it by the simulator's memory check)."""
MAX_PHOTONS = 10_000_000
"""Most photons per lit point and channel, as ``ringlight simulate --photons``: ten million
already take hours on a 24 x 24 grid."""
MAX_SEED = 2**32 - 1
"""Largest seed, as ``ringlight simulate --seed``."""

_RIGS: OrderedDict[tuple, SimulatedRig] = OrderedDict()
"""The last :data:`_KEPT_RIGS` rigs asked for, by :func:`rig_key`."""
_KEPT_RIGS = 4
_LIVE_RIGS: weakref.WeakValueDictionary = weakref.WeakValueDictionary()
"""Every rig still held (by a device or :data:`_RIGS`), by key: a camera and a projector of one
key always share one rig, however many others were made between their openings."""
_RIGS_LOCK = threading.Lock()


def _integer(key: str, value: str, low: int, high: int | None = None) -> int:
    """Option ``key``'s ``value`` (a string, as typed) as an integer in [low, high] (high None:
    no limit); OptionError naming the range otherwise."""
    try:
        number = int(value)
    except ValueError:
        number = None
    if number is None or number < low or (high is not None and number > high):
        allowed = f"from {low:,} to {high:,}" if high is not None else f"{low:,} or more"
        raise OptionError(RIG, key, value, f"must be an integer {allowed}")
    return number


def _grid_size(value: str) -> tuple[int, int]:
    """Option ``size`` ``"HxW"`` -> (height, width) in projector pixels, each side from
    MIN_SIDE to MAX_SIDE; OptionError otherwise."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
    if match is None or not all(MIN_SIDE <= int(side) <= MAX_SIDE for side in match.groups()):
        raise OptionError(RIG, "size", value, f"must be HxW projector pixels, at least {MIN_SIDE}x{MIN_SIDE} and "
                                              f"at most {MAX_SIDE}x{MAX_SIDE}, e.g. 24x24")
    return int(match[1]), int(match[2])


def _scene(value: str) -> str:
    """Option ``scene``: ``colorchecker``, a simulator preset or a scene JSON file; OptionError otherwise."""
    from ..simulate.presets import preset_names

    if value != "colorchecker" and value not in preset_names() and not os.path.exists(value):
        raise OptionError(RIG, "scene", value, f"must be colorchecker, a simulator preset "
                                               f"({', '.join(preset_names())}) or a scene JSON file")
    return value


def _load_scene(scene: str, size: tuple[int, int]):
    """The simulator's scene ``scene`` on a ``size`` grid. A preset is valid at its own size, so its
    refusal (a volume too large, a shape outside a small grid) is the ``size`` option's."""
    from ..simulate.presets import load_scene, preset_names
    from ..simulate.scene import SceneError

    try:
        return load_scene(scene, size=size)
    except SceneError as error:
        if scene not in preset_names():
            raise  # a scene file's own problem, which its message names
        raise OptionError(RIG, "size", f"{size[0]}x{size[1]}", str(error)) from None


def _make_rig(scene: str, size: tuple[int, int], photons: int, seed: int,
              progress: ProgressCallback | None) -> SimulatedRig:
    """A new rig over ``scene`` on a ``size`` (height, width) grid (the simulator runs for a preset)."""
    from ..simulate.transport import simulate_transport

    if scene == "colorchecker":
        windows = colorchecker_windows(*size)
    else:
        windows = simulate_transport(_load_scene(scene, size), photons=photons, seed=seed, progress=progress).windows
    return SimulatedRig(windows, seed=seed, options=key_options((scene, size, photons, seed)))


def rig_key(scene: str = "red-bead", size: str = "24x24", photons: str = "600", seed: str = "0",
            **unknown: str) -> tuple:
    """The key of a preset rig from its options, strings as typed by a user: ``scene``, ``size``
    HxW projector pixels (MIN_SIDE to MAX_SIDE each), ``photons`` per lit point and channel (1 to
    MAX_PHOTONS), ``seed`` (0 to MAX_SEED); a value out of range, an option of another name, or a
    scene the simulator refuses at that size (a volume too large) raises OptionError. Nothing is
    simulated: the scene is only loaded (about a millisecond)."""
    if unknown:
        name, value = next(iter(unknown.items()))
        raise OptionError(RIG, name, value, f"no such option of the simulated rig (its options: {OPTIONS})")
    key = (_scene(scene), _grid_size(size), _integer("photons", photons, 1, MAX_PHOTONS),
           _integer("seed", seed, 0, MAX_SEED))
    if key[0] != "colorchecker":
        _load_scene(key[0], key[1])
    return key


def key_options(key: tuple) -> dict[str, str]:
    """A :func:`rig_key`'s options, normalised, as :attr:`SimulatedRig.options` holds them."""
    scene, size, photons, seed = key
    return {"scene": scene, "size": f"{size[0]}x{size[1]}", "photons": str(photons), "seed": str(seed)}


def describe_rig(options: dict[str, str]) -> str:
    """A preset rig's options as the notes hold them: ``scene red-bead; size 24x24; ...``."""
    return "; ".join(f"{key} {value}" for key, value in options.items())


def preset_rig(progress: ProgressCallback | None = None, **options: str) -> SimulatedRig:
    """The rig over a simulator preset with ``options`` (:func:`rig_key`; made once per key, the
    last four kept, and shared by the camera and projector). Making one runs the simulator (about
    10 s for the default 24 x 24 at 600 photons on 2 cores): ``progress`` gets the fraction done
    and may raise Cancelled."""
    return _rig_for(rig_key(**options), progress)


def _rig_for(key: tuple, progress: ProgressCallback | None) -> SimulatedRig:
    """The rig of ``key``: the one a device still holds or one of the last four made, else a new one."""
    with _RIGS_LOCK:
        rig = _LIVE_RIGS.get(key)
        if rig is not None:
            _RIGS[key] = rig
            _RIGS.move_to_end(key)
            return rig
    rig = _make_rig(*key, progress)
    with _RIGS_LOCK:
        rig = _LIVE_RIGS.setdefault(key, rig)  # one made meanwhile by another thread is the one
        _RIGS[key] = rig
        while len(_RIGS) > _KEPT_RIGS:
            _RIGS.popitem(last=False)
    return rig


def simulated_camera(fail_after: str = "", progress: ProgressCallback | None = None,
                     **options: str) -> SimulatedCamera:
    """The ``simulated`` camera: a camera of the preset rig of ``options`` (:func:`rig_key`, made
    when it opens), which fails after ``fail_after`` captures (0 or more; empty: never; counted
    from this camera's making)."""
    after = _fail_after(fail_after)
    return SimulatedCamera(RigRequest(rig_key(**options), progress), after)


def simulated_projector(fail_after: str = "", progress: ProgressCallback | None = None,
                        **options: str) -> SimulatedProjector:
    """The ``simulated`` projector of the preset rig of ``options`` (:func:`rig_key`, made when it
    opens). ``fail_after``, the camera's option, is checked and kept for :func:`pair_problem`: an
    option for both devices gives it to both."""
    return SimulatedProjector(RigRequest(rig_key(**options), progress), 0.0, _fail_after(fail_after))


def _fail_after(value: str) -> int | None:
    """Option ``fail_after``: captures before the camera fails (0 or more), None when empty."""
    return _integer("fail_after", value, 0) if value else None


OPTIONS = "scene, size, photons, seed, fail_after"
"""The simulated devices' options, as messages list them."""

PLUGIN = HardwarePlugin(
    name="simulated",
    cameras={"simulated": simulated_camera},
    projectors={"simulated": simulated_projector},
    description=f"a virtual rig over a simulator preset (options: {OPTIONS})",
)
