"""The hardware plugin API: cameras and projectors, found through entry points.

A plugin is any installed package that declares, in its ``pyproject.toml``::

    [project.entry-points."ringlight.hardware"]
    mylab = "mylab_rig.ringlight_plugin:PLUGIN"

where ``PLUGIN`` is a :class:`HardwarePlugin`: a name and factories for the cameras and projectors
it offers. A factory takes keyword options (strings, from the wizard or ``ringlight capture
--option``, ``--camera-option``, ``--projector-option KEY=VALUE``) and returns an unopened
device; a device may say why it cannot work with the other (:func:`pair_problem`). Devices follow
the :class:`Camera` and :class:`Projector` protocols below; nothing here imports Qt (a Qt
projector window lives in ``ringlight.widgets``). A plugin that fails to import or is malformed is reported by
:func:`discover_plugins` and skipped; it never stops ringlight.

Units: exposures in seconds; frames are float32 linear raw values in camera counts (black level
not subtracted) of shape (rows, cols) or (rows, cols, 3); patterns are (H, W) float32 in [0, 1] in
projector pixels.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Protocol, runtime_checkable

import numpy as np

from ..errors import ProgressCallback, RinglightError

ENTRY_POINT_GROUP = "ringlight.hardware"


class HardwareError(RinglightError):
    """A device failed (not found, refused a setting, stopped answering)."""


class OptionError(HardwareError):
    """A device factory refused the value of one of its options (``key=value``, as typed).

    The message names the device, the option and the allowed values; ``key``, ``value`` and
    ``problem`` let a caller name the option as its user gave it (``--camera-option size=0x0``).
    """

    def __init__(self, device: str, key: str, value: str, problem: str):
        super().__init__(f"{device} option {key}={value}: {problem}")
        self.key = key
        self.value = value
        self.problem = problem


@runtime_checkable
class Camera(Protocol):
    """A linear camera."""

    def open(self) -> None: ...

    def close(self) -> None: ...

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """(rows, cols) or (rows, cols, 3) of captured frames."""

    @property
    def exposure_range(self) -> tuple[float, float]:
        """Shortest and longest exposure in seconds."""

    @property
    def saturation_level(self) -> float:
        """Raw value at and above which a pixel is saturated (e.g. 4095 for 12 bit)."""

    @property
    def black_level(self) -> float:
        """Raw value of no light."""

    def properties(self) -> dict[str, str]:
        """Free-form description (model, serial, bit depth, backend), for the dataset's notes."""

    def capture(self, exposure: float) -> np.ndarray:
        """One frame at ``exposure`` seconds: float32 raw values. Raises HardwareError."""


@runtime_checkable
class Projector(Protocol):
    """A projector showing patterns of its native size."""

    def open(self) -> None: ...

    def close(self) -> None: ...

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) in projector pixels."""

    @property
    def settle_time(self) -> float:
        """Seconds to wait after showing a pattern before capturing."""

    def show(self, pattern: np.ndarray) -> None:
        """Show an (H, W) pattern of values in [0, 1]."""

    def show_black(self) -> None: ...

    def show_white(self) -> None: ...


Factory = Callable[..., object]


@dataclass(frozen=True)
class HardwarePlugin:
    """What a plugin offers: ``cameras`` and ``projectors`` map device names to factories.

    ``unavailable``: a one-line reason when the plugin's SDK is missing (it names what to
    install); such a plugin is listed among the failures and offers no devices.
    """

    name: str
    cameras: dict[str, Factory] = field(default_factory=dict)
    projectors: dict[str, Factory] = field(default_factory=dict)
    description: str = ""
    unavailable: str = ""


@dataclass(frozen=True)
class Discovery:
    """Loaded plugins and the ones that failed, as ``(entry point, one-line reason)``."""

    plugins: tuple[HardwarePlugin, ...]
    failures: tuple[tuple[str, str], ...]

    def cameras(self) -> dict[str, Factory]:
        return {name: factory for plugin in self.plugins for name, factory in plugin.cameras.items()}

    def projectors(self) -> dict[str, Factory]:
        return {name: factory for plugin in self.plugins for name, factory in plugin.projectors.items()}


def discover_plugins(group: str = ENTRY_POINT_GROUP) -> Discovery:
    """Load every plugin of the entry-point ``group``; broken ones are listed, not raised."""
    plugins, failures = [], []
    for entry in sorted(entry_points(group=group), key=lambda entry: entry.name):
        try:
            plugin = entry.load()
        except Exception as error:  # a third-party plugin may fail in any way: report, go on
            failures.append((entry.name, f"failed to load {entry.value}: {type(error).__name__}: {error}"))
            continue
        if not isinstance(plugin, HardwarePlugin):
            failures.append((entry.name, f"{entry.value} is a {type(plugin).__name__}, not a HardwarePlugin"))
            continue
        if plugin.unavailable:
            failures.append((entry.name, plugin.unavailable))
            continue
        plugins.append(plugin)
    return Discovery(tuple(plugins), tuple(failures))


def make_device(factories: dict[str, Factory], name: str, options: dict[str, str] | None = None,
                progress: ProgressCallback | None = None):
    """Build device ``name`` with ``options``; HardwareError names the choices when unknown.

    A factory that names a ``progress`` parameter (one whose building takes a while, such as the
    simulated rig's) gets ``progress``, which receives the fraction done; others never see it."""
    if name not in factories:
        raise HardwareError(f"no device called {name!r}; available: {', '.join(sorted(factories)) or 'none'}")
    factory = factories[name]
    arguments = dict(options or {})
    if progress is not None and _names_progress(factory):
        arguments["progress"] = progress
    try:
        return factory(**arguments)
    except TypeError as error:
        raise HardwareError(f"device {name!r}: bad options {options}: {error}") from None


def pair_problem(camera, projector) -> str | None:
    """Why ``camera`` cannot film what ``projector`` shows, or None: each device may say so of the
    other through a ``pair_problem(other)`` method of its own (the simulated devices do:
    :func:`.simulated_rig.pair_problem`). Asked after both are made and before either opens."""
    for device, other in ((camera, projector), (projector, camera)):
        ask = getattr(device, "pair_problem", None)
        problem = ask(other) if callable(ask) else None
        if problem:
            return problem
    return None


def open_pair(camera, projector) -> None:
    """Open ``camera``, then ``projector``, once :func:`pair_problem` finds none (HardwareError
    naming it otherwise, before either opens: a simulated rig is made at its camera's opening); the
    camera is closed again when the projector fails to open."""
    problem = pair_problem(camera, projector)
    if problem is not None:
        raise HardwareError(problem)
    camera.open()
    try:
        projector.open()
    except BaseException:
        camera.close()
        raise


def _names_progress(factory: Factory) -> bool:
    try:
        parameter = inspect.signature(factory).parameters.get("progress")
    except (TypeError, ValueError):  # a builtin or extension without a signature
        return False
    return parameter is not None and parameter.kind in (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY)


def parse_options(pairs: list[str] | None) -> dict[str, str]:
    """``["key=value", ...]`` -> dict; HardwareError for an item without '='."""
    options = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise HardwareError(f"device option {pair!r} must be KEY=VALUE")
        options[key] = value
    return options
