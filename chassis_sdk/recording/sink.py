"""The Foxglove sink: one device's session published into a ``foxglove.Context``, for a
recording and a live view alike.

`FoxgloveSink` publishes everything one device does into a ``foxglove.Context``
(the `foxglove-sdk <https://docs.foxglove.dev/docs/sdk>`_): the raw bytes both ways,
every named stream decoded, the commands the host wrote decoded, odometry as a pose
and a transform, events as log lines, the link state. Whatever listens to that context
gets it: an MCAP file (`chassis_sdk.recording.mcap.McapRecording`) or the
Foxglove WebSocket server (``chassis-sdk serve``), or both at once.

Topics, for a device named ``chassis``::

    /chassis/raw/rx      bytes as they arrived, with their receive time  (JSON, base64)
    /chassis/raw/tx      every frame the host wrote, when it began to leave
    /chassis/commands    those frames decoded
    /chassis/{stream}    each stream (telemetry, power, odometry, events, ...) as JSON;
                         (`chassis_sdk.core.plain` writes them, with their JSON
                         schemas); a reading with the pack's ``voltage`` of a device
                         given ``battery=BatteryModel(...)`` with ``battery_percentage``
                         and ``battery_level`` beside it (left out while not known)
    /chassis/pose        foxglove.PoseInFrame in frame "odom"
    /tf                  foxglove.FrameTransforms odom -> base_link
    /chassis/log         events as foxglove.Log
    /chassis/link        the link state ({"state": "connected"}, ...)
"""

from __future__ import annotations

import base64
import datetime
import json
import logging
import math
import platform
import socket
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ..core.battery import BatteryLevel
from ..core.charge import battery_fields
from ..core.notifier import Notifier
from ..core.plain import json_schema, jsonable
from ..errors import install_hint
from .batch import AfterFrame

if TYPE_CHECKING:
    import foxglove

    from ..core.device import Device

__all__ = ["FoxgloveSink", "session_metadata"]

_log = logging.getLogger("chassis_sdk.recording")
_NS = 1_000_000_000
_BYTES_SCHEMA = {
    "type": "object",
    "properties": {"data": {"type": "string", "contentEncoding": "base64"}},
    "required": ["data"],
}
_LINK_SCHEMA = {
    "type": "object",
    "properties": {"state": {"type": "string"}},
    "required": ["state"],
}
#: The decoded commands: every type of command on one channel, each named by ``type``.
_COMMAND_SCHEMA = {
    "type": "object",
    "properties": {"type": {"type": "string"}},
    "required": ["type"],
}
#: Event kinds logged as warnings (the rest are information).
_WARNINGS = ("engaged", "hit", "offline", "error", "low", "critical", "stale", "lost")
#: The JSON schema of the state of charge beside a voltage (``battery_fields``; both
#: left out while it is not known).
_CHARGE_SCHEMA = {
    "battery_percentage": {"type": "number", "minimum": 0, "maximum": 100},
    "battery_level": json_schema(BatteryLevel),
}


def _needs_foxglove(what: str) -> ImportError:
    return ImportError(f"{what} needs the foxglove-sdk package: {install_hint('foxglove')}")


# --- JSON schemas of messages (core.plain writes them: one encoding, one schema) ---------


def _message_schema(msg: object) -> dict[str, Any]:
    schema = json_schema(type(msg))
    if schema.get("type") == "object":
        return schema
    return {"type": "object", "properties": {"value": schema}, "required": ["value"]}


def session_metadata(device: Device[Any, Any]) -> dict[str, str]:
    """What a recording says of its session: device, port, baud rate, versions, host."""
    from .._version import __version__
    from ..core.transport import backend_name

    return {
        "device": device.device_name,
        "device_class": f"{type(device).__module__}.{type(device).__qualname__}",
        "port": device.port,
        "baudrate": str(device.baudrate),
        "sdk_version": __version__,
        "transport": backend_name(),
        "python": platform.python_version(),
        "host": socket.gethostname(),
        "started": datetime.datetime.now(datetime.UTC).isoformat(),
    }


# --- the sink ------------------------------------------------------------------------------


class FoxgloveSink:
    """Publishes one device's session into a ``foxglove.Context`` (see the module
    docstring for the topics). It is the device's `Tap`
    and listens to its streams synchronously, so nothing is missed and nothing waits;
    encoding is skipped on a channel nobody listens to.

    Args:
        context: The context an MCAP writer or WebSocket server listens to.
        device: The device whose session this is.
        after_log: Called with the time after every message logged (an MCAP
            recording's periodic flush).
    """

    def __init__(
        self,
        context: foxglove.Context,
        device: Device[Any, Any],
        *,
        after_log: Callable[[float], None] | None = None,
    ) -> None:
        try:
            import foxglove
            import foxglove.channels as fc
            import foxglove.messages as fm
        except ImportError:
            raise _needs_foxglove("recording to MCAP or serving to Foxglove") from None
        self._fg, self._fm = foxglove, fm
        self._context = context
        self.device = device
        name = device.device_name
        self._prefix = f"/{name}"
        # Monotonic seconds -> epoch nanoseconds, fixed once per session.
        self._epoch_offset = time.time_ns() - int(time.monotonic() * _NS)
        self._after_log = after_log
        self._rx = self._json_channel("raw/rx", _BYTES_SCHEMA, "chassis_sdk.RawBytes")
        self._tx = self._json_channel("raw/tx", _BYTES_SCHEMA, "chassis_sdk.RawBytes")
        self._link = self._json_channel("link", _LINK_SCHEMA, "chassis_sdk.LinkState")
        self._commands: foxglove.Channel | None = None
        self._channels: dict[str, foxglove.Channel] = {}
        self._pose = fc.PoseInFrameChannel(f"{self._prefix}/pose", context=context)
        self._tf = fc.FrameTransformsChannel("/tf", context=context)
        self._log = fc.LogChannel(f"{self._prefix}/log", context=context)
        self._command_decoder = device.command_decoder()
        self._notifier: Notifier | None = None
        self.messages = 0
        # Work is queued and done in one batch after the loop's current callbacks, so
        # the application's task woken by a frame runs before the frame is recorded.
        self._after = AfterFrame(device.port)
        self._later = self._after.later

    # --- attaching ---------------------------------------------------------------------------

    def attach(self) -> None:
        """Start: see every byte of the device's links, every message of its named
        streams and every change of its link state."""
        device = self.device
        self._after = AfterFrame(device.port)  # the loop it is attached on
        self._later = self._after.later
        notifier = self._notifier = Notifier(device)
        for stream_name in notifier.stream_names:
            notifier.listen(stream_name, self._stream_logger(stream_name))
        notifier.listen_states(self._on_state)
        notifier.add_tap(self)
        self.link_state(device.connection_state.value, time.monotonic())

    def detach(self) -> None:
        """Stop (the device goes on, unrecorded); what is queued is logged first."""
        self._after.drain()
        if self._notifier is not None:
            self._notifier.close()
            self._notifier = None

    # --- what is logged -----------------------------------------------------------------------

    def rx(self, data: bytes, now: float) -> None:
        """Bytes arrived (the device's `Tap`)."""
        self._later(self._bytes, self._rx, data, now)

    def tx(self, data: bytes, now: float) -> None:
        """A frame began to leave (the device's `Tap`)."""
        self._later(self._sent, data, now)

    def link_state(self, state: str, now: float) -> None:
        """The link went to ``state`` (also for a recorder that opens links itself)."""
        self._later(self._json, self._link, {"state": state}, now)

    def _sent(self, data: bytes, now: float) -> None:
        self._bytes(self._tx, data, now)
        decoder = self._command_decoder
        if decoder is not None:
            for command in decoder.feed(data, now):
                if self._commands is None:
                    name = f"chassis_sdk.{self.device.device_name}.Command"
                    self._commands = self._json_channel("commands", _COMMAND_SCHEMA, name)
                payload = {"type": type(command).__name__, **jsonable(command)}
                self._json(self._commands, payload, now)

    def _on_state(self, state: Any) -> None:
        self.link_state(str(state.value), time.monotonic())

    def _bytes(self, channel: foxglove.Channel, data: bytes, now: float) -> None:
        if channel.has_sinks():
            self._emit(channel, {"data": base64.b64encode(data).decode("ascii")}, now)

    def _stream_logger(self, stream: str) -> Callable[[Any], None]:
        def listener(msg: Any) -> None:
            self._later(log, msg, time.monotonic())

        def log(msg: Any, now: float) -> None:
            channel = self._channels.get(stream)
            # A reading of the pack's voltage, of a device with a model: the charge too.
            charge = self.device.battery_model is not None and hasattr(msg, "voltage")
            if channel is None:
                schema = _message_schema(msg)
                if charge:
                    schema = {**schema, "properties": {**schema["properties"], **_CHARGE_SCHEMA}}
                channel = self._channels[stream] = self._json_channel(
                    stream, schema, _schema_name(self.device.device_name, msg)
                )
            payload = jsonable(msg)
            if charge:
                payload.update(battery_fields(self.device))
            self._json(channel, payload, now)
            if stream == "odometry":
                self._odometry(msg, now)
            elif stream == "events":
                self._event(msg, now)

        return listener

    def _json(self, channel: foxglove.Channel, payload: dict[str, Any], now: float) -> None:
        if channel.has_sinks():
            self._emit(channel, payload, now)

    def _emit(self, channel: foxglove.Channel, payload: dict[str, Any], now: float) -> None:
        channel.log(
            json.dumps(payload, default=_jsonify, allow_nan=True).encode(),
            log_time=self._ns(now),
        )
        self._logged(now)

    def _logged(self, now: float) -> None:
        self.messages += 1
        if self._after_log is not None:
            self._after_log(now)

    def _odometry(self, odom: Any, now: float) -> None:
        fm = self._fm
        stamp = self._stamp(getattr(odom, "timestamp", 0.0) or now)
        half = odom.heading / 2.0
        rotation = fm.Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))
        position = fm.Vector3(x=odom.x, y=odom.y, z=0.0)
        log_time = self._ns(now)
        if self._pose.has_sinks():
            pose = fm.Pose(position=position, orientation=rotation)
            self._pose.log(
                fm.PoseInFrame(timestamp=stamp, frame_id="odom", pose=pose), log_time=log_time
            )
            self._logged(now)
        if self._tf.has_sinks():
            transform = fm.FrameTransform(
                timestamp=stamp,
                parent_frame_id="odom",
                child_frame_id="base_link",
                translation=position,
                rotation=rotation,
            )
            self._tf.log(fm.FrameTransforms(transforms=[transform]), log_time=log_time)
            self._logged(now)

    def _event(self, event: Any, now: float) -> None:
        if not self._log.has_sinks():
            return
        fm = self._fm
        kind = str(getattr(getattr(event, "kind", None), "value", ""))
        level = fm.LogLevel.Warning if kind.endswith(_WARNINGS) else fm.LogLevel.Info
        self._log.log(
            fm.Log(
                timestamp=self._stamp(getattr(event, "timestamp", 0.0) or now),
                level=level,
                message=str(event),
                name=f"{self.device.device_name} {self.device.port}",
            ),
            log_time=self._ns(now),
        )
        self._logged(now)

    # --- helpers --------------------------------------------------------------------------------

    def _json_channel(self, topic: str, schema: dict[str, Any], name: str) -> foxglove.Channel:
        fg = self._fg
        channel: foxglove.Channel = fg.Channel(
            f"{self._prefix}/{topic}",
            schema=fg.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode()),
            message_encoding="json",
            context=self._context,
        )
        return channel

    def _ns(self, monotonic: float) -> int:
        return int(monotonic * _NS) + self._epoch_offset

    def _stamp(self, monotonic: float) -> Any:
        ns = self._ns(monotonic)
        return self._fm.Timestamp(sec=ns // _NS, nsec=ns % _NS)


def _jsonify(value: object) -> Any:
    if isinstance(value, bytes | bytearray):
        return base64.b64encode(value).decode("ascii")
    return str(value)


def _schema_name(device: str, msg: object) -> str:
    return f"chassis_sdk.{device}.{type(msg).__qualname__}"
