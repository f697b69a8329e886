"""Serve one device live to the Foxglove app over its WebSocket protocol.

Every topic of :mod:`chassis_sdk.core.recording` goes out as it happens (decoded
streams, odometry pose and ``/tf``, events, link state, raw bytes), and the app can:

* call the services ``stop``, ``emergency_stop``, ``release_emergency_stop`` and
  ``clear_faults`` (those the device has; ``std_srvs/Trigger``-shaped JSON: the
  response is ``{"success": bool, "message": str}``);
* drive from the **Teleop** panel: a client channel whose schema is
  ``geometry_msgs/Twist`` (or ``geometry_msgs/msg/Twist``), JSON-encoded, becomes
  ``set_velocity(linear.x, angular.z)`` under the device's deadman: when the panel stops
  publishing, the robot stops within ``command_timeout``; when the panel's channel goes
  away (the app closes, the network drops), it stops at once.

A message that is not a well-formed Twist of finite numbers is rejected, counted,
logged and reported to the app as a status message; it never moves the robot.

The server binds to 127.0.0.1 unless told otherwise; the protocol has no
authentication, so expose it through an SSH tunnel (see docs/foxglove.md), or with
``read_only`` when only watching.

The WebSocket subprotocol is ``foxglove.sdk.v1`` (foxglove-sdk's name for the
protocol formerly called ``foxglove.websocket.v1``; the messages are the same).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from .core.device import Device
from .core.recording import FoxgloveSink, session_metadata

__all__ = ["SERVICES", "TWIST_SCHEMAS", "FoxgloveServer"]

_log = logging.getLogger("chassis_sdk.live")
#: Schema names of a client channel taken as velocity commands.
TWIST_SCHEMAS = ("geometry_msgs/Twist", "geometry_msgs/msg/Twist")
#: The services offered, by the device method each calls (those the device has).
SERVICES = ("stop", "emergency_stop", "release_emergency_stop", "clear_faults")
#: With ``read_only``: only these (they can only stop the robot).
SAFE_SERVICES = ("stop", "emergency_stop")
_SERVICE_TIMEOUT = 5.0
_TRIGGER_REQUEST = {"type": "object", "properties": {}}
_TRIGGER_RESPONSE = {
    "type": "object",
    "properties": {"success": {"type": "boolean"}, "message": {"type": "string"}},
}


class FoxgloveServer:
    """One connected device, served live to the Foxglove app (see the module docstring).

    Use ``async with FoxgloveServer(robot) as server:`` inside ``async with robot:``;
    the address to open in the app is :attr:`url`.

    Args:
        device: A device (connected, or about to be: the server follows its link).
        host: Address to bind; ``127.0.0.1`` (default) serves this computer only.
        port: TCP port; 0 picks a free one (:attr:`port` says which).
        read_only: Take no velocity and offer only ``stop`` and ``emergency_stop``.
        record: Also record the session to this ``.mcap`` file.
        name: The server's name, as the app shows it.
    """

    def __init__(
        self,
        device: Device[Any, Any],
        *,
        host: str = "127.0.0.1",
        port: int = 8765,
        read_only: bool = False,
        record: str | Path | None = None,
        name: str | None = None,
    ) -> None:
        try:
            import foxglove
        except ImportError:
            raise ImportError(
                "serving to Foxglove needs foxglove-sdk: pip install 'chassis-sdk[foxglove]'"
            ) from None
        if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
            raise ValueError(f"port must be 0..65535, got {port!r}")
        self._fg = foxglove
        self.device = device
        self.host = host
        self._port = port
        self.read_only = bool(read_only)
        self.record = Path(record) if record is not None else None
        if self.record is not None and self.record.suffix.lower() != ".mcap":
            raise ValueError(f"record must name a .mcap file, got {str(record)!r}")
        self.name = name or f"chassis-sdk {device.kind} {device.port}"
        #: Client messages rejected (not a well-formed Twist, or refused by the device).
        self.rejected = 0
        #: Velocity commands taken from clients.
        self.commands = 0
        self._context = foxglove.Context()
        self._sink: FoxgloveSink | None = None
        self._server: Any = None
        self._writer: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._teleop: set[tuple[int, int]] = set()  # (client id, client channel id)

    @property
    def port(self) -> int:
        """The TCP port served (the one picked, for 0)."""
        return int(self._server.port) if self._server is not None else self._port

    @property
    def url(self) -> str:
        """The address to open in the Foxglove app."""
        return f"ws://{self.host}:{self.port}"

    async def __aenter__(self) -> Self:
        self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def start(self) -> None:
        """Start serving (from the event loop's thread)."""
        from foxglove.websocket import Capability

        self._loop = asyncio.get_running_loop()
        if self.record is not None:
            self._writer = self._fg.open_mcap(
                self.record, allow_overwrite=True, context=self._context
            )
            self._writer.write_metadata("chassis_sdk", session_metadata(self.device))
        self._sink = FoxgloveSink(self._context, self.device)
        self._sink.attach()
        wanted = SAFE_SERVICES if self.read_only else SERVICES
        services = [self._service(n) for n in wanted if callable(getattr(self.device, n, None))]
        capabilities = [Capability.Services]
        if not self.read_only:
            capabilities.append(Capability.ClientPublish)
        self._server = self._fg.start_server(
            name=self.name,
            host=self.host,
            port=self._port,
            capabilities=capabilities,
            supported_encodings=["json"],
            services=services,
            server_listener=self._listener(),
            context=self._context,
        )
        _log.info("serving %s to Foxglove at %s", self.device.port, self.url)

    def stop(self) -> None:
        """Stop serving (the device goes on; close it to stop the robot)."""
        if self._server is not None:
            self._server.stop()
            self._server = None
        if self._sink is not None:
            self._sink.detach()
            self._sink = None
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    # --- services (called on the server's threads) ------------------------------------------

    def _service(self, method: str) -> Any:
        fg = self._fg

        def schema(name: str, body: dict[str, Any]) -> Any:
            return fg.MessageSchema(
                encoding="json",
                schema=fg.Schema(name=name, encoding="jsonschema", data=json.dumps(body).encode()),
            )

        return fg.Service(
            name=method,
            schema=fg.ServiceSchema(
                name="std_srvs/Trigger",
                request=schema("std_srvs/Trigger_Request", _TRIGGER_REQUEST),
                response=schema("std_srvs/Trigger_Response", _TRIGGER_RESPONSE),
            ),
            handler=lambda request: self._call(method),
        )

    def _call(self, method: str) -> bytes:
        ok, message = self._run_in_loop(getattr(self.device, method))
        _log.info("service %s: %s", method, message)
        return json.dumps({"success": ok, "message": message}).encode()

    def _run_in_loop(self, call: Callable[[], Coroutine[Any, Any, Any]]) -> tuple[bool, str]:
        loop = self._loop
        if loop is None or loop.is_closed():
            return False, "the server is stopping"
        try:
            asyncio.run_coroutine_threadsafe(call(), loop).result(_SERVICE_TIMEOUT)
        except TimeoutError:
            return False, f"no answer within {_SERVICE_TIMEOUT:g} s"
        except Exception as exc:  # the device's own error, for the app to show
            return False, str(exc) or type(exc).__name__
        return True, "done"

    # --- client publishing (the server's threads) ----------------------------------------

    def _listener(self) -> Any:
        from foxglove.websocket import ServerListener

        server = self

        class Listener(ServerListener):
            def on_client_advertise(self, client: Any, channel: Any) -> None:
                server._advertised(client, channel)

            def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
                server._unadvertised(client, client_channel_id)

            def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
                server._message(client, client_channel_id, data)

        return Listener()

    def _advertised(self, client: Any, channel: Any) -> None:
        if channel.schema_name in TWIST_SCHEMAS and channel.encoding == "json":
            self._teleop.add((client.id, channel.id))
            _log.info("client %d drives on %s", client.id, channel.topic)
        else:
            self._reject(
                f"channel {channel.topic!r} ({channel.schema_name}, {channel.encoding}) "
                f"is not taken: only JSON {TWIST_SCHEMAS[0]} drives"
            )

    def _unadvertised(self, client: Any, client_channel_id: int) -> None:
        key = (client.id, client_channel_id)
        if key in self._teleop:
            self._teleop.discard(key)
            self._in_loop(self._stop_now)  # the panel went away: stop now, not at the deadman

    def _message(self, client: Any, client_channel_id: int, data: bytes) -> None:
        if (client.id, client_channel_id) not in self._teleop:
            return  # reported once when advertised
        try:
            linear, angular = _twist(data)
        except ValueError as exc:
            self._reject(f"velocity rejected: {exc}")
            return
        self._in_loop(lambda: self._drive(linear, angular))

    def _in_loop(self, callback: Callable[[], None]) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(callback)

    def _drive(self, linear: float, angular: float) -> None:
        task = asyncio.ensure_future(self.device.set_velocity(linear, angular))

        def done(task: asyncio.Future[None]) -> None:
            if task.cancelled():
                return
            exc = task.exception()
            if exc is None:
                self.commands += 1
            else:
                self._reject(f"velocity ({linear}, {angular}) refused: {exc}")

        task.add_done_callback(done)

    def _stop_now(self) -> None:
        if self.device.is_connected:
            asyncio.ensure_future(self.device.stop()).add_done_callback(_ignore_result)

    def _reject(self, message: str) -> None:
        self.rejected += 1
        _log.warning("%s", message)
        server = self._server
        if server is not None:
            from foxglove.websocket import StatusLevel

            server.publish_status(message, StatusLevel.Warning, id=f"reject-{time.monotonic()}")


def _ignore_result(task: asyncio.Future[None]) -> None:
    if not task.cancelled():
        task.exception()  # retrieved: a stop on a link that just dropped is no news


def _twist(data: bytes) -> tuple[float, float]:
    """``(linear.x, angular.z)`` of a JSON Twist, or ValueError saying what is wrong."""
    try:
        msg = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        raise ValueError("not JSON") from None
    if not isinstance(msg, dict):
        raise ValueError("not a JSON object")
    values = []
    for part, axis in (("linear", "x"), ("angular", "z")):
        vector = msg.get(part, {})
        if not isinstance(vector, dict):
            raise ValueError(f"{part} is not an object")
        value = vector.get(axis, 0.0)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{part}.{axis} is not a number: {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{part}.{axis} is not finite: {value!r}")
        values.append(float(value))
    return values[0], values[1]
