"""The device registry: every device the SDK can talk to, simulate, record and decode.

A device is one package (``devices/chassis/``, ``devices/board/``, or an installed
third-party package) that provides a :class:`DeviceProfile`: its device class, its
codec, its firmware model and simulator, examples of its frames, and optionally its
part of the command line. ``chassis-sdk``, :mod:`chassis_sdk.capture` and the fuzz
harness loop over :func:`profiles`; nothing outside a device's own package names it.

Third parties add a device by installing a package that declares an entry point in the
group ``chassis_sdk.devices`` whose object is a :class:`DeviceProfile` (or a function
returning one)::

    # pyproject.toml of the package "acme-mower"
    [project.entry-points."chassis_sdk.devices"]
    mower = "acme_mower:PROFILE"

Tests and scripts may also :func:`register` a profile at run time. See "Adding a
device" in the docs for a whole device in one file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Coroutine, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import import_module, metadata
from typing import TYPE_CHECKING, Any

from ..core.device import Device
from ..core.framing import FrameDecoder
from ..core.simulator import Firmware, SimulatorServer

if TYPE_CHECKING:
    from ..core.columns import Columns

__all__ = ["ENTRY_POINT_GROUP", "DeviceProfile", "profile", "profiles", "register", "unregister"]

#: Where installed packages declare their devices.
ENTRY_POINT_GROUP = "chassis_sdk.devices"
#: The devices that ship with the SDK: name -> "module:attribute" of the profile (the
#: same strings pyproject.toml declares as entry points, so a source checkout that is
#: not installed finds them too).
BUILTIN = {
    "chassis": "chassis_sdk.devices.chassis.profile:PROFILE",
    "board": "chassis_sdk.devices.board.profile:PROFILE",
}

_log = logging.getLogger("chassis_sdk.devices")

#: A frame as bytes and the message it decodes to (fed with timestamp 0.0).
Example = tuple[bytes, object]


@dataclass(frozen=True, slots=True)
class DeviceProfile:
    """Everything the SDK's tools need to know of one device.

    Attributes:
        name: Short lowercase name: ``--protocol NAME`` on the command line,
            ``Diagnosis.device``, ``detect``'s answer.
        summary: One line for help texts.
        device: The :class:`~chassis_sdk.core.device.Device` subclass.
        decoder: Makes a decoder of what the device sends.
        command_decoder: Makes a decoder of what the host sends (simulator, captures,
            fuzzing).
        firmware: Makes a sans-IO firmware model (the simulator's).
        simulator: Makes a simulator server: ``simulator(tcp_port=None, faults=None)``.
        examples: Frames the device sends, each with the message it decodes to; the
            codec contract tests and the fuzzer's seeds use them (at least one).
        command_examples: The same for frames the host sends.
        max_buffered: The most bytes a decoder may hold after ``feed`` returns (its
            largest frame, plus any look-ahead); the fuzzer checks it.
        recognised_by: What ``detect`` hears from this device unprompted, for messages.
        streams: The device's stream methods the MQTT bridge publishes
            (``telemetry/{stream}``).
        requests: The read-only request methods the bridge answers (``request/{name}``).
        identity: The requests whose results make the bridge's retained ``info``.
        features: What the device has, for ``info`` (``{"servos": 2, ...}``).
        demo: ``chassis-sdk demo --device NAME``: drives the simulator, narrating.
        info: ``chassis-sdk info PORT``: ``info(port, baudrate, timeout)``; a generic
            report if ``None``.
        monitor: ``chassis-sdk monitor PORT``: ``monitor(port, baudrate, seconds,
            as_json)``.
        plot: ``chassis-sdk plot``: ``plot(data, commands, figure)`` draws the capture
            decoded into arrays (:class:`~chassis_sdk.core.columns.Columns`), and the
            host's commands if the capture holds any, into a matplotlib figure; a
            generic plot if ``None``. Both decoders must describe their ``layout``.
    """

    name: str
    summary: str
    device: type[Device[Any, Any]]
    decoder: Callable[[], FrameDecoder[Any]]
    command_decoder: Callable[[], FrameDecoder[Any]]
    firmware: Callable[[], Firmware]
    simulator: Callable[..., SimulatorServer]
    examples: Sequence[Example]
    command_examples: Sequence[Example]
    max_buffered: int
    recognised_by: str
    streams: tuple[str, ...] = ()
    requests: tuple[str, ...] = ()
    identity: tuple[str, ...] = ()
    features: Mapping[str, object] = field(default_factory=dict)
    demo: Callable[[], Coroutine[Any, Any, None]] | None = None
    info: Callable[[str, int, float], Coroutine[Any, Any, None]] | None = None
    monitor: Callable[[str, int, float | None, bool], Coroutine[Any, Any, None]] | None = None
    plot: Callable[[Columns, Columns, Any], None] | None = None

    def __post_init__(self) -> None:
        if not self.name or not self.name.isidentifier() or self.name != self.name.lower():
            raise ValueError(f"a device name is a lowercase identifier, got {self.name!r}")
        if not self.examples or not self.command_examples:
            raise ValueError(f"device {self.name!r}: examples of both directions are needed")
        if self.plot is not None and any(
            type(make()).layout is None for make in (self.decoder, self.command_decoder)
        ):
            raise ValueError(f"device {self.name!r}: a plot needs both decoders' layout")


_registered: dict[str, DeviceProfile] = {}
_installed: dict[str, DeviceProfile] | None = None


def _load(target: str | metadata.EntryPoint) -> DeviceProfile:
    if isinstance(target, str):
        module, _, attribute = target.partition(":")
        obj: Any = getattr(import_module(module), attribute)
    else:
        obj = target.load()
    if callable(obj) and not isinstance(obj, DeviceProfile):
        obj = obj()
    if not isinstance(obj, DeviceProfile):
        raise TypeError(f"{target!r} is not a DeviceProfile")
    return obj


def _discover() -> dict[str, DeviceProfile]:
    """The built-in devices and every installed entry point, loaded once."""
    global _installed
    if _installed is None:
        found = {name: _load(target) for name, target in BUILTIN.items()}
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            if BUILTIN.get(ep.name) == ep.value:
                continue  # the SDK's own devices, declared for discovery by others
            try:
                loaded = _load(ep)
            except Exception as exc:  # one broken plugin must not break every tool
                _log.warning(
                    "device entry point %s = %s failed to load: %r", ep.name, ep.value, exc
                )
                continue
            if loaded.name in found:
                _log.warning("device %r from %s ignored: the name is taken", loaded.name, ep.value)
                continue
            found[loaded.name] = loaded
        _installed = found
    return _installed


def profiles() -> dict[str, DeviceProfile]:
    """Every known device by name: built in, installed (entry points in the group
    ``chassis_sdk.devices``), and registered at run time, in that order."""
    return {**_discover(), **_registered}


def profile(name: str) -> DeviceProfile:
    """The device called ``name``.

    Raises:
        ValueError: No such device (the message lists the known ones).
    """
    known = profiles()
    try:
        return known[name]
    except KeyError:
        raise ValueError(f"unknown device {name!r}; known: {', '.join(known)}") from None


def register(device: DeviceProfile) -> None:
    """Add a device at run time (tests, scripts); :func:`unregister` removes it.

    Raises:
        ValueError: A device of that name is already known.
    """
    if device.name in profiles():
        raise ValueError(f"a device named {device.name!r} is already registered")
    _registered[device.name] = device


def unregister(name: str) -> None:
    """Remove a device added with :func:`register` (no error if it is not there)."""
    _registered.pop(name, None)
