"""Serve one device live to the Foxglove app over its WebSocket protocol.

Every topic of `chassis_sdk.recording.sink` goes out as it happens (decoded
streams, odometry pose and ``/tf``, events, link state, raw bytes), and the app can:

* call the services ``stop``, ``emergency_stop``, ``release_emergency_stop`` and
  ``clear_faults`` (those the device has; ``std_srvs/Trigger``-shaped JSON: the
  response is ``{"success": bool, "message": str}``);
* drive from the **Teleop** panel: a client channel whose schema is
  ``geometry_msgs/Twist`` (or ``geometry_msgs/msg/Twist``), JSON-encoded, makes its
  client a source of the device's motion core (kind ``"foxglove"``, streaming), and each
  Twist a velocity ``(linear.x, angular.z)`` offered to it under the device's deadman:
  the core writes the newest at most once per ``WRITE_PERIOD``, refuses it while motion
  is blocked or another source drives, and after an e-stop wants a zero first. When the
  panel stops publishing, the robot stops within ``command_timeout``; when the panel's
  channel goes away (the app closes, the network drops) or is advertised again as
  something else than a Twist, it stops at once if that client was driving.

A message that is not a well-formed Twist of finite numbers (read strictly by
`chassis_sdk.integrations.inbound.command_object`: UTF-8 only, no duplicate keys, bounded
size, depth and numbers) is refused, counted, logged and reported to the app as a
warning status (rate-limited and summarised by `chassis_sdk.integrations.inbound.Refusals`);
it never moves the robot. No message can make a callback fail unreported: any error in
one is caught, counted in `FoxgloveServer.errors` and reported the same way.

Who may connect
---------------
foxglove-sdk's server has no hook to look at a handshake, so it is bound to a private
loopback address and port, and a small WebSocket front (on the ``websockets`` package,
in a thread of its own) takes the connections on the address asked for. The front
checks each handshake before anything reaches the protocol: the ``Origin`` header
(RFC 6455 §10.2: a page in the operator's browser must not drive the robot; no
``Origin`` (a native client), the Foxglove and Lichtblick apps' origins and each
``allow_origins`` entry are let in, anything else gets HTTP 403) and, with ``token``,
the token (HTTP 401 without it). Then it relays the frames both ways unchanged,
except that a client channel advertised again under the same id is first unadvertised
(foxglove-sdk would silently keep the first schema, so a channel re-advertised as
``std_msgs/String`` would go on driving). Each relayed connection proves itself to the
server with a secret (new each time the server starts), so a client that reaches the
private port directly cannot drive, release an e-stop or clear faults: every service
but ``stop`` and ``emergency_stop`` requires the proof. What the private port does
expose, to any local user or program (loopback is open to every account, and
``ss -lt`` lists it), without the token or the Origin check: every stream, and the
calls ``stop`` and ``emergency_stop``.

The front relays only text frames that are JSON objects (others are refused and
reported), and at most `MAX_CLIENT_CHANNELS` client channels per connection.
Leaving the server (``async with``, `FoxgloveServer.aclose`) first stops a robot
a Teleop client was driving, then shuts down the front and foxglove-sdk's server in
worker threads, so a client that does not read cannot block the event loop.

The WebSocket subprotocol is ``foxglove.sdk.v1`` (foxglove-sdk's name for the
protocol formerly called ``foxglove.websocket.v1``; the messages are the same).

How it is built
---------------
`FoxgloveServer` is the one object its user talks to, and it holds the server's
lifetime: foxglove-sdk's server on its private address, the front, the recording or
sink, and leaving them in order. Its collaborators do the rest, by job: the front and
the handshake's Origin and token checks (`foxglove_front`),
the counts and reports of what was refused (`foxglove_reports`),
and what the app's clients may do, the services and the Teleop channels
(`_Channels` and `_Services`, here).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import hmac
import json
import logging
import math
import secrets
import threading
from collections.abc import Callable, Coroutine, Iterable
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import anyio
import anyio.to_thread

from ...core.device import Device
from ...core.motion import MotionSource
from ...errors import ChassisError, install_hint
from ...recording.mcap import McapRecording
from ...recording.sink import FoxgloveSink
from ..inbound import CommandError, command_object
from .front import (
    APP_ORIGINS,
    HELLO_ID,
    HELLO_TOPIC,
    MAX_CLIENT_CHANNELS,
    Front,
    Gate,
    check_access,
    is_loopback,
    private_loopback,
)
from .front import MIN_TOKEN_LENGTH as MIN_TOKEN_LENGTH
from .front import SUBPROTOCOL as SUBPROTOCOL
from .reports import REPORT_INTERVAL as REPORT_INTERVAL
from .reports import STATUS_HANDSHAKE as STATUS_HANDSHAKE
from .reports import STATUS_REFUSALS as STATUS_REFUSALS
from .reports import Reports, shown

__all__ = [
    "APP_ORIGINS",
    "MAX_CLIENT_CHANNELS",
    "SAFE_SERVICES",
    "SERVICES",
    "TWIST_SCHEMAS",
    "FoxgloveServer",
    "check_access",
    "is_loopback",
]

_log = logging.getLogger("chassis_sdk.integrations.foxglove")

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
#: The longest the front's thread is waited for on leaving (beyond it, it is left to
#: end on its own: a daemon thread).
_FRONT_JOIN = 3.0


class FoxgloveServer:
    """One connected device, served live to the Foxglove app (see the module docstring).

    Use ``async with FoxgloveServer(robot) as server:`` inside ``async with robot:``;
    the address to open in the app is [`url`][chassis_sdk.integrations.foxglove.FoxgloveServer.url].

    Args:
        device: A device (connected, or about to be: the server follows its link).
        host: Address to bind; ``127.0.0.1`` (default) serves this computer only.
        port: TCP port; 0 picks a free one (`port` says which).
        read_only: Take no velocity and offer only ``stop`` and ``emergency_stop``.
        record: Also record the session to this ``.mcap`` file, by
            [`McapRecording`][chassis_sdk.recording.mcap.McapRecording] (compressed, flushed every
            second: a hard kill loses at most the last second).
        name: The server's name, as the app shows it.
        allow_origins: ``Origin`` values let in besides no ``Origin`` and
            `APP_ORIGINS` (``scheme://host[:port]``, e.g. a self-hosted Lichtblick).
        token: A secret every client must give: as the query parameter ``token``
            (``ws://robot:8765/?token=...``: the only way the app's browser can), or as
            ``Authorization: Bearer ...``. At least 16 printable ASCII characters. It is
            compared in constant time and never logged or shown.
        allow_no_token: Serve a host beyond loopback without a token (a network whose
            every machine is trusted); without it that is refused.

    Raises:
        ValueError: A bad option, or a host beyond loopback without ``token`` (and
            without ``allow_no_token``).
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
        allow_origins: Iterable[str] = (),
        token: str | None = None,
        allow_no_token: bool = False,
    ) -> None:
        try:
            import foxglove
            import websockets  # noqa: F401  (the front)
        except ImportError:
            raise ImportError(
                "serving to Foxglove needs foxglove-sdk and websockets: " + install_hint("foxglove")
            ) from None
        if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
            raise ValueError(f"port must be 0..65535, got {port!r}")
        allowed = check_access(
            host, allow_origins=allow_origins, token=token, allow_no_token=allow_no_token
        )
        self._gate = Gate(allowed, token)
        self._fg = foxglove
        self.device = device
        self.host = host
        self._port = port
        self.read_only = bool(read_only)
        self.record = Path(record) if record is not None else None
        if self.record is not None and self.record.suffix.lower() != ".mcap":
            raise ValueError(f"record must name a .mcap file, got {str(record)!r}")
        self.name = name or f"chassis-sdk {device.device_name} {device.port}"
        self._context = foxglove.Context()
        self._sink: FoxgloveSink | None = None
        self._server: Any = None
        self._front: Front | None = None
        self._recording: McapRecording | None = None
        self._secret = secrets.token_hex(16)
        # Its collaborators, by job: the counts and reports (to the app through
        # foxglove-sdk's server, while there is one), and what clients may do.
        self._reports = Reports(lambda: self._server)
        self._channels = _Channels(self, self._reports, self._secret)
        self._services = _Services(self, self._reports, self._channels)

    @property
    def rejected(self) -> int:
        """Client messages refused (not a well-formed Twist, on a channel not taken,
        from a client that did not come through the front, or refused by the device)."""
        return self._reports.rejected

    @property
    def errors(self) -> int:
        """Errors caught in the server's callbacks (each also reported)."""
        return self._reports.errors

    @property
    def refused_connections(self) -> int:
        """Connections refused at the handshake (a bad Origin, a missing or wrong token)."""
        return self._reports.refused_connections

    @property
    def commands(self) -> int:
        """Velocity commands from clients taken by the device's motion core (it writes
        the newest at most once per ``WRITE_PERIOD``)."""
        return self._channels.commands

    @property
    def port(self) -> int:
        """The TCP port served (the one picked, for 0)."""
        return self._front.port if self._front is not None else self._port

    @property
    def url(self) -> str:
        """The address to open in the Foxglove app (without the token)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    # The clients' state, kept readable by its former names (the tests look at it).
    _teleop = property(lambda self: self._channels.teleop)
    _fronted = property(lambda self: self._channels.fronted)
    _sources = property(lambda self: self._channels.sources)

    async def __aenter__(self) -> Self:
        self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()

    def start(self) -> None:
        """Start serving (from the event loop's thread).

        Raises:
            RuntimeError: The address cannot be bound (taken, or not this computer's).
        """
        from foxglove.websocket import Capability

        loop = asyncio.get_running_loop()
        # Fresh per-run state: the new server numbers its clients from 1 again, so a
        # client id proven (or driving) in the last run means nothing in this one.
        self._secret = secrets.token_hex(16)
        self._channels.reset(loop, self._secret)
        self._reports.restart()  # fresh reporters: the last stop took every interval as passed
        services = self._services.offered()
        capabilities = [Capability.Services]
        if not self.read_only:
            capabilities.append(Capability.ClientPublish)
        listener = self._channels.listener()

        def start_server(host: str) -> Any:
            return self._fg.start_server(
                name=self.name,
                host=host,
                port=0,  # private: only the front connects (see private_loopback)
                capabilities=capabilities,
                supported_encodings=["json"],
                services=services,
                server_listener=listener,
                context=self._context,
            )

        backend_host = private_loopback()
        try:
            self._server = start_server(backend_host)
        except RuntimeError:
            if backend_host == "127.0.0.1":
                raise
            backend_host = "127.0.0.1"  # a Linux whose loopback has only 127.0.0.1
            self._server = start_server(backend_host)
        front = Front(
            f"ws://{backend_host}:{self._server.port}",
            gate=self._gate,
            reports=self._reports,
            secret=None if self.read_only else self._secret,
        )
        try:
            front.start(self.host, self._port)
        except BaseException:
            self._server.stop()
            self._server = None
            raise
        self._front = front
        if self.record is not None:
            # The one recorder, publishing in the server's context: its sink is the
            # server's, so the file and the app get the same messages.
            self._recording = McapRecording(self.record, self.device, context=self._context)
            self._sink = self._recording.sink
        else:
            self._sink = FoxgloveSink(self._context, self.device)
            self._sink.attach()
        _log.info(
            "serving %s to Foxglove at %s (origins: no Origin, %s; token: %s)",
            self.device.port,
            self.url,
            ", ".join(sorted(self._gate.allowed)),
            "required" if self._gate.token is not None else "none",
        )

    async def aclose(self) -> None:
        """Stop serving without blocking the event loop (what ``async with`` does).

        If a Teleop client was driving, the robot is stopped first (zero velocity now,
        not at the deadman); the device goes on. Then the front and foxglove-sdk's
        server are shut down in worker threads, each waited for a bounded time.
        """
        await self._channels.close()
        front, self._front = self._front, None
        server = self._server
        server_stopping = False
        try:
            if front is not None:
                front.signal_stop()
                await anyio.to_thread.run_sync(front.join, _FRONT_JOIN, abandon_on_cancel=True)
                self._reports.flush_final()  # to the app, through the server still up
            self._server = None
            if server is not None:
                server_stopping = True
                await anyio.to_thread.run_sync(server.stop, abandon_on_cancel=True)
        finally:
            self._server = None
            if not server_stopping and server is not None:
                # Interrupted (cancelled): foxglove-sdk's server is still stopped, in a
                # thread of its own, not waited for.
                threading.Thread(
                    target=server.stop, name="chassis-sdk-foxglove-stop", daemon=True
                ).start()
            self._release()

    def stop(self) -> None:
        """Stop serving, blocking until the front's thread ends (up to a few seconds
        with a client that does not read): from async code, ``await aclose()``.

        If a Teleop client was driving, a stop of the robot is queued in the loop."""
        self._channels.close_soon()
        front, self._front = self._front, None
        if front is not None:
            front.signal_stop()
            front.join(_FRONT_JOIN)
            self._reports.flush_final()
        server, self._server = self._server, None
        if server is not None:
            server.stop()
        self._release()

    def _release(self) -> None:
        sink, self._sink = self._sink, None
        recording, self._recording = self._recording, None
        if recording is not None:
            recording.close()  # detaches its sink (the server's), then finishes the file
        elif sink is not None:
            sink.detach()


class _Channels:
    """The clients' channels: the front's proof that a client came through it, and
    the Teleop panel's (a client channel of JSON Twists, each a velocity under the
    device's deadman).

    Each Teleop client is a source of its own in the device's motion core (kind
    ``"foxglove"``, streaming), made when it advertises a Twist channel and closed when
    its last one goes away: the core paces what is written (the newest, at most once
    per ``WRITE_PERIOD``), arbitrates between the clients and the other surfaces, and
    refuses velocity while motion is blocked.

    Its callbacks come from foxglove-sdk's threads: they check and parse there, then hand
    each Twist to the event loop (``call_soon_threadsafe``, in the order they came), where
    its client's source takes it. A stop or e-stop service is handed over the same way,
    after the Twists that came before it, so none of them is written after its zero.
    It reads the server's ``device`` and ``read_only`` as they are when it acts.
    """

    def __init__(self, owner: FoxgloveServer, reports: Reports, secret: str) -> None:
        self._owner = owner
        self._reports = reports
        # Guards what foxglove-sdk's threads, the front's and the loop share: the
        # channels taken and the clients proven.
        self._lock = threading.Lock()
        #: Velocity commands taken by the motion core from clients.
        self.commands = 0
        #: The event loop the server runs in (set by :meth:`reset`).
        self.loop: asyncio.AbstractEventLoop | None = None
        self._secret = secret
        self.teleop: dict[tuple[int, int], str] = {}  # (client id, channel id) -> topic
        self.fronted: set[int] = set()  # client ids proven to come through the front
        # In the loop only: each Teleop client's source, and its channels that drive.
        self.sources: dict[int, MotionSource] = {}
        self._live: dict[int, set[int]] = {}
        # Under the lock: each client channel's newest Twist not yet handed to the loop
        # (topic, linear, angular, whether a zero was replaced on the way).
        self._newest: dict[tuple[int, int], tuple[str, float, float, bool]] = {}
        # Set on leaving: no Twist is taken any more (the robot has been stopped).
        self._closing = False

    def reset(self, loop: asyncio.AbstractEventLoop, secret: str) -> None:
        """Fresh per-run state, for a server in ``loop`` whose front proves itself with
        ``secret``; the counts go on."""
        self.loop = loop
        with self._lock:
            self.teleop = {}
            self.fronted = set()
            self._closing = False
        self._close_sources()  # a last run's (left by `stop`, not closed in its loop)
        self._secret = secret

    def end(self) -> None:
        """Take no more Twists."""
        with self._lock:
            self._closing = True
            self.teleop.clear()

    async def close(self) -> None:
        """`end`, and close every client's source (in the loop): the robot stops now
        if one of them was driving."""
        self.end()
        self._close_sources()
        await anyio.lowlevel.checkpoint()

    def close_soon(self) -> None:
        """`end`, and queue the closing of the clients' sources in the loop."""
        self.end()
        self._in_loop(self._close_sources)

    async def stop(self, client_id: int) -> None:
        """(In the loop.) The ``stop`` service called by client ``client_id``: its
        Teleop source's stop (which counts as its neutral after an e-stop), or the
        device's if it has none. A stop always acts, whoever drives."""
        source = self.sources.get(client_id)
        if source is not None:
            source.stop()
        else:
            await self._owner.device.stop()

    def _close_sources(self) -> None:
        """(In the loop.) Close every client's source: one that was driving stops the
        robot (quietly if the port is closed)."""
        sources, self.sources = self.sources, {}
        self._live = {}
        with self._lock:
            self._newest.clear()
        for source in sources.values():
            source.close()

    # --- client publishing (the server's threads) ----------------------------------------

    def listener(self) -> Any:
        """foxglove-sdk's listener for what clients publish (advertise, unadvertise,
        message)."""
        from foxglove.websocket import ServerListener

        channels = self

        # Every callback is guarded: an exception escaping one is only logged by
        # foxglove-sdk ("Callback failed"), neither counted nor shown to the operator.
        class Listener(ServerListener):
            def on_client_advertise(self, client: Any, channel: Any) -> None:
                try:
                    channels._advertised(client, channel)
                except Exception as exc:
                    channels._reports.failed("advertise", exc)

            def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
                try:
                    channels._unadvertised(client, client_channel_id)
                except Exception as exc:
                    channels._reports.failed("unadvertise", exc)

            def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
                try:
                    channels._message(client, client_channel_id, data)
                except Exception as exc:
                    channels._reports.failed("message", exc)

        return Listener()

    def is_fronted(self, client_id: int) -> bool:
        """Whether the client came through the front (it gave the proof)."""
        with self._lock:
            return client_id in self.fronted

    def _advertised(self, client: Any, channel: Any) -> None:
        key = (client.id, channel.id)
        if channel.id == HELLO_ID:
            topic = str(channel.topic)
            proof = topic.removeprefix(HELLO_TOPIC)
            if topic.startswith(HELLO_TOPIC) and hmac.compare_digest(
                proof.encode(), self._secret.encode()
            ):
                with self._lock:
                    self.fronted.add(client.id)
                return
            self._reports.refuse(f"client {client.id}", "a channel on the front's reserved id")
            return
        is_twist = channel.schema_name in TWIST_SCHEMAS and channel.encoding == "json"
        if is_twist and not self.is_fronted(client.id):
            self._reports.refuse(
                f"channel {shown(channel.topic)}",
                "the client did not come through the front (Origin and token checks)",
            )
        elif is_twist:
            with self._lock:
                if self._closing:
                    return  # leaving: the robot has been stopped
                self.teleop[key] = shown(channel.topic)
            self._in_loop(functools.partial(self._opened, key))
            _log.info("client %d drives on %s", client.id, shown(channel.topic))
            return
        else:
            self._reports.refuse(
                f"channel {shown(channel.topic)}",
                f"{shown(channel.schema_name)} ({shown(channel.encoding)}) is not taken: "
                f"only JSON {TWIST_SCHEMAS[0]} drives",
            )
        self._drop_teleop(key)  # a Twist channel advertised again as anything else

    def _unadvertised(self, client: Any, client_channel_id: int) -> None:
        if client_channel_id == HELLO_ID:
            with self._lock:
                self.fronted.discard(client.id)  # the connection is closing
        self._drop_teleop((client.id, client_channel_id))

    def _drop_teleop(self, key: tuple[int, int]) -> None:
        """The channel no longer drives: if its client was driving, stop now, not at
        the deadman (in the loop, after the Twists that came before)."""
        with self._lock:
            if self.teleop.pop(key, None) is None:
                return
        self._in_loop(functools.partial(self._dropped, key))

    def _message(self, client: Any, client_channel_id: int, data: bytes) -> None:
        key = (client.id, client_channel_id)
        with self._lock:
            topic = self.teleop.get(key)
        if topic is None:
            self._reports.refuse(f"channel {client_channel_id}", "a message on a channel not taken")
            return
        try:
            linear, angular = _twist(data)
        except CommandError as exc:
            self._reports.refuse(f"velocity on {topic}", str(exc))
            return
        # Velocity is state: one hand-over per client channel waits in the loop's queue,
        # taking the newest Twist when it runs, so a flood queues no work and a stop
        # service waits behind one hand-over at most. A zero replaced on the way is still
        # given first (the neutral the core may want after an e-stop).
        with self._lock:
            held = self._newest.get(key)
            zero = held is not None and (held[3] or (held[1] == 0 and held[2] == 0))
            self._newest[key] = (topic, linear, angular, zero)
        if held is None:
            self._in_loop(functools.partial(self._hand_over, key))

    def _in_loop(self, callback: Callable[[], None]) -> None:
        loop = self.loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop closed in between
                loop.call_soon_threadsafe(self._guarded, callback)

    def _guarded(self, callback: Callable[[], None]) -> None:
        try:
            callback()
        except Exception as exc:
            name = getattr(getattr(callback, "func", callback), "__name__", "callback")
            self._reports.failed(name, exc)

    # --- in the event loop ---------------------------------------------------------------

    def _opened(self, key: tuple[int, int]) -> None:
        """A Twist channel was taken: its client's source, made with the first one."""
        if self._closing:
            return
        client_id, channel_id = key
        if client_id not in self.sources:
            self.sources[client_id] = self._owner.device.motion.source(
                f"foxglove client {client_id}", kind="foxglove", streaming=True
            )
        self._live.setdefault(client_id, set()).add(channel_id)

    def _dropped(self, key: tuple[int, int]) -> None:
        """A Twist channel went away: the robot stops now if its client drove; the
        client's source is closed with its last channel."""
        client_id, channel_id = key
        live = self._live.get(client_id)
        source = self.sources.get(client_id)
        if live is None or source is None:
            return
        live.discard(channel_id)
        if not live:
            del self._live[client_id], self.sources[client_id]
            source.close()  # stops the robot if this client was driving
        elif source.driving:
            with contextlib.suppress(ChassisError):
                source.stop()

    def _hand_over(self, key: tuple[int, int]) -> None:
        """The newest Twist of a client channel, to its source."""
        with self._lock:
            held = self._newest.pop(key, None)
        if held is None:
            return
        topic, linear, angular, zero = held
        if zero and (linear or angular):
            self._velocity(key, topic, 0.0, 0.0)
        self._velocity(key, topic, linear, angular)

    def _velocity(self, key: tuple[int, int], topic: str, linear: float, angular: float) -> None:
        """One Twist, offered to its client's source (the core paces the writes)."""
        client_id, channel_id = key
        source = self.sources.get(client_id)
        if self._closing or source is None or channel_id not in self._live.get(client_id, ()):
            return  # leaving, or the channel went away meanwhile: it never drives
        try:
            refusal = source.set_velocity(linear, angular)
        except ValueError as exc:  # out of the device's range: refused, not written
            self._reports.refuse(f"velocity on {topic}", str(exc))
            return
        except ChassisError as exc:  # not connected: this command is lost
            self._reports.refuse(f"velocity on {topic}", f"not written: {exc}")
            return
        if refusal is not None:
            self._reports.refuse(f"velocity on {topic}", f"refused: {refusal.detail}")
            return
        self.commands += 1


class _Services:
    """The services the app may call (``std_srvs/Trigger``-shaped): each runs the
    device method of its name in the event loop, waited for a bounded time. Those that
    can let the robot move again only for a client that came through the front.

    Called on foxglove-sdk's threads; it reads the server's ``device`` and
    ``read_only`` as they are when it acts.
    """

    def __init__(self, owner: FoxgloveServer, reports: Reports, channels: _Channels) -> None:
        self._owner = owner
        self._reports = reports
        self._channels = channels

    def offered(self) -> list[Any]:
        """foxglove-sdk's services to offer: those of `SERVICES` (or, read-only,
        `SAFE_SERVICES`) that the device has."""
        wanted = SAFE_SERVICES if self._owner.read_only else SERVICES
        device = self._owner.device
        return [self._service(n) for n in wanted if callable(getattr(device, n, None))]

    def _service(self, method: str) -> Any:
        import foxglove as fg

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
            handler=lambda request: self._called(method, request),
        )

    def _called(self, method: str, request: Any) -> bytes:
        try:
            if method not in SAFE_SERVICES and not self._channels.is_fronted(request.client_id):
                # A stop is safe from anyone; what can let the robot move again is not.
                self._reports.refuse(
                    f"service {method}", "the client did not come through the front"
                )
                ok, message = False, "refused: the connection was not checked"
            else:
                call = getattr(self._owner.device, method)
                if method == "stop":  # the client's own stop: its source's neutral too
                    call = functools.partial(self._channels.stop, request.client_id)
                ok, message = self._run_in_loop(call)
                _log.info("service %s: %s", method, message)
        except Exception as exc:  # never let a service call fail unreported
            self._reports.failed(f"service {method}", exc)
            ok, message = False, "internal error"
        return json.dumps({"success": ok, "message": message}).encode()

    def _run_in_loop(self, call: Callable[[], Coroutine[Any, Any, Any]]) -> tuple[bool, str]:
        loop = self._channels.loop
        if loop is None or loop.is_closed():
            return False, "the server is stopping"
        future = asyncio.run_coroutine_threadsafe(call(), loop)
        try:
            future.result(_SERVICE_TIMEOUT)
        except TimeoutError:
            # Reported as not done: it must not be done later (a release of an
            # e-stop the operator was told did not happen).
            future.cancel()
            return False, f"no answer within {_SERVICE_TIMEOUT:g} s"
        except concurrent.futures.CancelledError:
            return False, "cancelled (the server is stopping)"
        except Exception as exc:  # the device's own error, for the app to show
            return False, str(exc) or type(exc).__name__
        return True, "done"


def _twist(data: bytes) -> tuple[float, float]:
    """``(linear.x, angular.z)`` of a JSON Twist, or CommandError saying what is wrong."""
    msg = command_object(data)
    values = []
    for part, axis in (("linear", "x"), ("angular", "z")):
        vector = msg.get(part, {})
        if not isinstance(vector, dict):
            raise CommandError(f"{part} is not an object")
        value = vector.get(axis, 0.0)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CommandError(f"{part}.{axis} is not a number: {str(value)[:40]!r}")
        value = float(value)
        if not math.isfinite(value):
            raise CommandError(f"{part}.{axis} is not finite: {value!r}")
        values.append(value)
    return values[0], values[1]
