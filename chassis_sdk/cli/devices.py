"""Each device's own part of ``chassis-sdk``: its demo, ``info``, ``monitor`` and
``plot``, found by device name like the devices themselves.

The built-in devices' parts are `chassis_sdk.cli.chassis` and
`chassis_sdk.cli.board`; an installed package adds one by declaring an entry point
in the group ``chassis_sdk.cli`` whose object is a `DeviceCommands`. A device
without one gets the generic commands (info from its first frame, a monitor of its
streams, a plot of every numeric field).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from importlib import metadata
from typing import TYPE_CHECKING, Any, Protocol

from ..devices import DeviceProfile, profile, resolve

if TYPE_CHECKING:
    from ..recording.columns import Columns

__all__ = ["ENTRY_POINT_GROUP", "DeviceCommands", "MonitorCommand", "checked", "commands"]

#: Where installed packages declare their devices' commands.
ENTRY_POINT_GROUP = "chassis_sdk.cli"
BUILTIN = {
    "chassis": "chassis_sdk.cli.chassis:COMMANDS",
    "board": "chassis_sdk.cli.board:COMMANDS",
}
_log = logging.getLogger("chassis_sdk.cli")


class MonitorCommand(Protocol):
    """A device's own ``monitor``: follow the device on ``port`` for ``seconds``
    (``None``: until cancelled), as lines or JSON, opening it with ``options``."""

    def __call__(
        self, port: str, baudrate: int, seconds: float | None, as_json: bool, **options: Any
    ) -> Coroutine[Any, Any, None]: ...


@dataclass(frozen=True, slots=True)
class DeviceCommands:
    """A device's own commands; ``None`` for any it leaves to the generic one.

    Attributes:
        demo: ``chassis-sdk demo --device NAME``: drives the simulator, narrating.
        info: ``chassis-sdk info PORT``: ``info(port, baudrate, timeout, **options)``,
            the options being the device constructor's (the profile's battery model).
        monitor: ``chassis-sdk monitor PORT``: ``monitor(port, baudrate, seconds,
            as_json, **options)``, the options being the device constructor's (the
            profile's battery model, ``read_only=True``, ...).
        plot: ``chassis-sdk plot``: ``plot(data, commands, figure)`` draws the capture
            decoded into arrays ([`Columns`][chassis_sdk.recording.columns.Columns]), and
            the host's commands if the capture holds any, into a matplotlib figure.
            Both of the device's decoders must describe their ``layout``.
    """

    demo: Callable[[], Coroutine[Any, Any, None]] | None = None
    info: Callable[..., Coroutine[Any, Any, None]] | None = None
    monitor: MonitorCommand | None = None
    plot: Callable[[Columns, Columns, Any], None] | None = None


_GENERIC = DeviceCommands()


def commands(device: str) -> DeviceCommands:
    """The commands of the device called ``device`` (the generic ones if it has none)."""
    target: Any = BUILTIN.get(device)
    if target is None:
        found = [ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP) if ep.name == device]
        if not found:
            return _GENERIC
        try:
            target = found[0].load()
        except Exception as exc:  # a broken plugin leaves the generic commands
            _log.warning("commands of device %r failed to load: %r", device, exc)
            return _GENERIC
    loaded = resolve(target)
    if not isinstance(loaded, DeviceCommands):
        raise TypeError(f"{target!r} is not a DeviceCommands")
    return checked(profile(device), loaded)


def checked(device: DeviceProfile, own: DeviceCommands) -> DeviceCommands:
    """``own`` if it fits ``device``.

    Raises:
        ValueError: It has a plot, but one of the device's decoders describes no
            ``layout`` (a plot is drawn from the capture decoded into columns).
    """
    codec = device.codec
    if own.plot is not None and any(
        type(make()).layout is None for make in (codec.decoder, codec.command_decoder)
    ):
        raise ValueError(f"device {device.name!r}: a plot needs both decoders' layout")
    return own
