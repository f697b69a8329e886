"""The device registry: every device the SDK can talk to, simulate, record and decode.

A device is one package (``devices/chassis/``, ``devices/board/``, or an installed
third-party package) that provides a `DeviceProfile`: its device class, its
codec (`Codec`), its firmware model, and what a bridge may publish and answer of
it (`Remote`). ``chassis-sdk``, the recorders and the fuzz harness loop over
[`profiles`][chassis_sdk.devices.profiles]; nothing outside a device's own package names it.

Third parties add a device by installing a package that declares an entry point in the
group ``chassis_sdk.devices`` whose object is a `DeviceProfile` (or a function
returning one)::

    # pyproject.toml of the package "acme-mower"
    [project.entry-points."chassis_sdk.devices"]
    mower = "acme_mower:PROFILE"

Loading is lazy: `names` reads no profile, [`profile`][chassis_sdk.devices.profile] loads one, and a
profile's ``device`` and ``firmware`` may be ``"module:attribute"`` strings, imported
on first use (so listing devices or decoding a capture never loads the runtime).
Tests and scripts may also `register` a profile at run time. See "Adding a
device" in the docs for a whole device in one file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from importlib import metadata

    from ..core.device import Device
    from ..core.firmware import Firmware
    from ..core.framing import FrameDecoder

__all__ = [
    "ENTRY_POINT_GROUP",
    "Codec",
    "DeviceProfile",
    "Remote",
    "names",
    "profile",
    "profiles",
    "register",
    "resolve",
    "unregister",
]

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


def resolve(target: str | Any) -> Any:
    """``"module:attribute"`` imported (anything else returned as it is)."""
    if not isinstance(target, str):
        return target
    module, sep, attribute = target.partition(":")
    if not sep or not module or not attribute:
        raise ValueError(f"expected 'module:attribute', got {target!r}")
    return getattr(import_module(module), attribute)


@dataclass(frozen=True, slots=True)
class Codec:
    """What decoding a device's bytes needs (captures, the fuzzer, the contract tests).

    Attributes:
        decoder: Makes a decoder of what the device sends.
        command_decoder: Makes a decoder of what the host sends (simulator, captures,
            fuzzing).
        examples: Frames the device sends, each with the message it decodes to; the
            codec contract tests and the fuzzer's seeds use them (at least one).
        command_examples: The same for frames the host sends.
        max_buffered: The most bytes a decoder may hold after ``feed`` returns (its
            largest frame, plus any look-ahead); the fuzzer checks it.
    """

    decoder: Callable[[], FrameDecoder[Any]]
    command_decoder: Callable[[], FrameDecoder[Any]]
    examples: Sequence[Example]
    command_examples: Sequence[Example]
    max_buffered: int

    def __post_init__(self) -> None:
        if not self.examples or not self.command_examples:
            raise ValueError("a codec needs examples of both directions")


@dataclass(frozen=True, slots=True)
class Remote:
    """What a bridge (MQTT, ROS 2) publishes and answers of a device.

    Attributes:
        streams: The device's stream methods published (``telemetry/{stream}``).
        requests: The read-only request methods answered (``request/{name}``).
        identity: The requests whose results make the retained ``info``.
        features: What the device has, for ``info`` (``{"servos": 2, ...}``).
    """

    streams: tuple[str, ...] = ()
    requests: tuple[str, ...] = ()
    identity: tuple[str, ...] = ()
    features: Mapping[str, object] = field(default_factory=dict)


class DeviceProfile:
    """One device, as the SDK's tools know it.

    Args:
        name: Short lowercase name: ``--device NAME`` on the command line,
            ``Diagnosis.device``, ``detect``'s answer.
        summary: One line for help texts.
        recognised_by: What ``detect`` hears from this device unprompted, for messages.
        device: The [`Device`][chassis_sdk.core.device.Device] subclass, or its
            ``"module:attribute"`` (imported on first use).
        firmware: Makes a sans-IO firmware model (the simulator's), or its
            ``"module:attribute"``.
        codec: Its decoders and examples.
        remote: What bridges publish and answer.
    """

    __slots__ = ("_device", "_firmware", "codec", "name", "recognised_by", "remote", "summary")

    def __init__(
        self,
        *,
        name: str,
        summary: str,
        recognised_by: str,
        device: type[Device[Any, Any]] | str,
        firmware: Callable[[], Firmware] | str,
        codec: Codec,
        remote: Remote | None = None,
    ) -> None:
        if not name or not name.isidentifier() or name != name.lower():
            raise ValueError(f"a device name is a lowercase identifier, got {name!r}")
        if not isinstance(codec, Codec):
            raise TypeError(f"device {name!r}: codec must be a Codec, got {codec!r}")
        self.name = name
        self.summary = summary
        self.recognised_by = recognised_by
        self.codec = codec
        self.remote = Remote() if remote is None else remote
        self._device = device
        self._firmware = firmware

    @property
    def device(self) -> type[Device[Any, Any]]:
        """The device class (imported now if it was given as a string)."""
        if isinstance(self._device, str):
            self._device = resolve(self._device)
        return self._device  # type: ignore[return-value]

    @property
    def firmware(self) -> Callable[[], Firmware]:
        """Makes the firmware model (imported now if it was given as a string)."""
        if isinstance(self._firmware, str):
            self._firmware = resolve(self._firmware)
        return self._firmware  # type: ignore[return-value]

    def __repr__(self) -> str:
        return f"<DeviceProfile {self.name!r}: {self.summary}>"


_registered: dict[str, DeviceProfile] = {}
_loaded: dict[str, DeviceProfile] = {}
_installed: dict[str, metadata.EntryPoint] | None = None
_broken: set[str] = set()  # entry points that failed to load (until read anew)


def _load(target: str | metadata.EntryPoint) -> DeviceProfile:
    obj: Any = resolve(target) if isinstance(target, str) else target.load()
    if callable(obj) and not isinstance(obj, DeviceProfile):
        obj = obj()
    if not isinstance(obj, DeviceProfile):
        raise TypeError(f"{target!r} is not a DeviceProfile")
    return obj


def _entry_points() -> dict[str, metadata.EntryPoint]:
    """The entry points of installed devices (the SDK's own excluded), read once."""
    global _installed
    if _installed is None:
        from importlib import metadata  # 30 ms: only when a device is looked up

        for name in [n for n in _loaded if n not in BUILTIN]:
            del _loaded[name]  # read anew with the entry points
        _broken.clear()
        _installed = {}
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.name in BUILTIN:
                if BUILTIN[ep.name] != ep.value:  # the SDK's own are declared there too
                    _log.warning("device %r from %s ignored: the name is taken", ep.name, ep.value)
                continue
            _installed[ep.name] = ep
    return _installed


def names() -> list[str]:
    """The names of every known device, without loading any of them."""
    return list(dict.fromkeys([*BUILTIN, *_entry_points(), *_registered]))


def _get(name: str) -> DeviceProfile | None:
    if name in _registered:
        return _registered[name]
    if name not in _loaded:
        if name in BUILTIN:
            _loaded[name] = _load(BUILTIN[name])
        elif (ep := _entry_points().get(name)) is not None and name not in _broken:
            try:
                loaded = _load(ep)
            except Exception as exc:  # one broken plugin must not break every tool
                _log.warning("device entry point %s = %s failed to load: %r", name, ep.value, exc)
                _broken.add(name)  # said once, not on every lookup
                return None
            if loaded.name != name:
                _log.warning(
                    "device entry point %s = %s is named %r: known as %r",
                    name,
                    ep.value,
                    loaded.name,
                    name,
                )
            _loaded[name] = loaded
        else:
            return None
    return _loaded[name]


def profiles() -> dict[str, DeviceProfile]:
    """Every known device by name: built in, installed (entry points in the group
    ``chassis_sdk.devices``), and registered at run time, in that order."""
    return {name: p for name in names() if (p := _get(name)) is not None}


def profile(name: str) -> DeviceProfile:
    """The device called ``name`` (only its profile is loaded).

    Raises:
        ValueError: No such device (the message lists the known ones).
    """
    found = _get(name)
    if found is None:
        raise ValueError(f"unknown device {name!r}; known: {', '.join(names())}")
    return found


def register(device: DeviceProfile) -> None:
    """Add a device at run time (tests, scripts); `unregister` removes it.

    Raises:
        ValueError: A device of that name is already known.
    """
    if device.name in names():
        raise ValueError(f"a device named {device.name!r} is already registered")
    _registered[device.name] = device


def unregister(name: str) -> None:
    """Remove a device added with `register` (no error if it is not there)."""
    _registered.pop(name, None)
