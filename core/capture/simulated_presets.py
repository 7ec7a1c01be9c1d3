"""The ``simulated`` hardware plugin: rigs over the simulator's presets, asked for by options.

A user's options (``scene``, ``size``, ``photons``, ``seed``; ``fail_after`` the camera's) are
checked and turned into a rig's key (:func:`rig_key`) before anything is simulated, so that the
camera's and the projector's can be compared (:func:`.simulated_rig.pair_problem`); the rig
itself (:class:`.simulated_rig.SimulatedRig`) is made when a device opens, once per key, and
shared by the devices of that key.
"""

from __future__ import annotations

import os
import re
import threading
import weakref
from collections import OrderedDict

from .hardware import HardwarePlugin, OptionError, ProgressCallback
from .simulated_rig import (SensorModel, SimulatedCamera, SimulatedProjector, SimulatedRig, colorchecker_windows,
                            key_options)

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


class RigRequest:
    """A preset rig asked for by its options (:func:`rig_key`) and made when a device first needs
    it (:func:`preset_rig`), with ``progress``: the simulated devices' factories validate their
    options and compare them (:func:`.simulated_rig.pair_problem`) before anything is simulated."""

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
