"""Serve one device live to the Foxglove app over its WebSocket protocol.

Every topic of :mod:`chassis_sdk.recording.sink` goes out as it happens (decoded
streams, odometry pose and ``/tf``, events, link state, raw bytes), and the app can:

* call the services ``stop``, ``emergency_stop``, ``release_emergency_stop`` and
  ``clear_faults`` (those the device has; ``std_srvs/Trigger``-shaped JSON: the
  response is ``{"success": bool, "message": str}``);
* drive from the **Teleop** panel: a client channel whose schema is
  ``geometry_msgs/Twist`` (or ``geometry_msgs/msg/Twist``), JSON-encoded, becomes
  ``set_velocity(linear.x, angular.z)`` under the device's deadman: when the panel stops
  publishing, the robot stops within ``command_timeout``; when the panel's channel goes
  away (the app closes, the network drops) or is advertised again as something else
  than a Twist, it stops at once.

A message that is not a well-formed Twist of finite numbers (read strictly by
:func:`chassis_sdk.integrations.inbound.command_object`: UTF-8 only, no duplicate keys, bounded
size, depth and numbers) is refused, counted, logged and reported to the app as a
warning status (rate-limited and summarised by :class:`chassis_sdk.integrations.inbound.Refusals`);
it never moves the robot. No message can make a callback fail unreported: any error in
one is caught, counted in :attr:`FoxgloveServer.errors` and reported the same way.

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
reported), and at most :data:`MAX_CLIENT_CHANNELS` client channels per connection.
Leaving the server (``async with``, :meth:`FoxgloveServer.aclose`) first stops a robot
a Teleop client was driving, then shuts down the front and foxglove-sdk's server in
worker threads, so a client that does not read cannot block the event loop.

The WebSocket subprotocol is ``foxglove.sdk.v1`` (foxglove-sdk's name for the
protocol formerly called ``foxglove.websocket.v1``; the messages are the same).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import hmac
import http
import ipaddress
import json
import logging
import math
import re
import secrets
import struct
import sys
import threading
import time
from collections.abc import Callable, Coroutine, Iterable
from pathlib import Path
from types import TracebackType
from typing import Any, Self
from urllib.parse import parse_qs, urlsplit

import anyio
import anyio.to_thread

from ..core.device import Device
from ..errors import ChassisError
from ..recording.mcap import McapRecording
from ..recording.sink import FoxgloveSink
from .inbound import CommandError, RefusalReport, Refusals, command_object

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


class _Redact(logging.Filter):
    """Takes tokens out of what ``websockets`` logs for the front: at DEBUG it logs
    each request line (``GET /?token=...``) and header (``Authorization: ...``)."""

    _SECRET = re.compile(r"(token=)[^&\s]*|(authorization: ).*", re.IGNORECASE)

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        redacted = self._SECRET.sub(lambda m: (m.group(1) or m.group(2)) + "[redacted]", text)
        if redacted != text:
            record.msg, record.args = redacted, ()
        return True


#: The front's own ``websockets`` log (connections opened, refused, closed).
_front_log = logging.getLogger("chassis_sdk.integrations.foxglove.front")
_front_log.addFilter(_Redact())
#: Schema names of a client channel taken as velocity commands.
TWIST_SCHEMAS = ("geometry_msgs/Twist", "geometry_msgs/msg/Twist")
#: The services offered, by the device method each calls (those the device has).
SERVICES = ("stop", "emergency_stop", "release_emergency_stop", "clear_faults")
#: With ``read_only``: only these (they can only stop the robot).
SAFE_SERVICES = ("stop", "emergency_stop")
#: ``Origin`` values let in without ``allow_origins``: the Foxglove web app (and its
#: former address), and ``file://``, which the Foxglove Studio and Lichtblick desktop
#: apps send (Electron pages loaded from files). Lichtblick's web app is self-hosted:
#: give its address with ``allow_origins``.
APP_ORIGINS = ("https://app.foxglove.dev", "https://studio.foxglove.dev", "file://")
#: The subprotocol spoken (the only one foxglove-sdk's server accepts).
SUBPROTOCOL = "foxglove.sdk.v1"
_SERVICE_TIMEOUT = 5.0
_TRIGGER_REQUEST = {"type": "object", "properties": {}}
_TRIGGER_RESPONSE = {
    "type": "object",
    "properties": {"success": {"type": "boolean"}, "message": {"type": "string"}},
}
#: Refusals are reported at most this often (seconds), the ones in between summarised.
REPORT_INTERVAL = 1.0
#: The shortest token taken (a shorter one can be guessed over the network).
MIN_TOKEN_LENGTH = 16
#: The client channel id the front uses for its proof; clients may not use it.
_HELLO_ID = 0xFFFFFFFF
_HELLO_TOPIC = "/_chassis_sdk/front/"
_CLIENT_MESSAGE = 0x01  # binary opcode, client -> server: channel id, payload
#: The largest frame a client may send the front (a Twist is about 60 bytes; the
#: largest protocol message a client sends is an advertise with its schemas).
_MAX_CLIENT_FRAME = 1 << 20
#: The most client channels one connection may have advertised at a time (the front
#: keeps a record of each; a Teleop panel needs one).
MAX_CLIENT_CHANNELS = 256
#: The front's ``websockets`` close and open timeouts (seconds): how long a closing
#: connection whose peer does not read, or a handshake that never completes, can hold
#: the front's shutdown.
_FRONT_TIMEOUT = 1.0
#: The longest the front's thread is waited for on leaving (beyond it, it is left to
#: end on its own: a daemon thread).
_FRONT_JOIN = 3.0
#: The ids of the warning statuses, one per kind of report: a new summary replaces the
#: one the app shows instead of piling up.
STATUS_REFUSALS = "chassis-sdk-refusals"
STATUS_HANDSHAKE = "chassis-sdk-handshake"


def is_loopback(host: str) -> bool:
    """Whether ``host`` names this computer only (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to anything


def _origin_key(origin: str) -> str:
    """An origin as compared: lowercase, no trailing slash (browsers send none, but a
    user may type one)."""
    key = origin.strip().lower()
    return key if key == "file://" else key.rstrip("/")


def check_access(
    host: str,
    *,
    allow_origins: Iterable[str] = (),
    token: str | None = None,
    allow_no_token: bool = False,
) -> frozenset[str]:
    """Check :class:`FoxgloveServer`'s access options (as it does), before anything
    opens; return the origins let in.

    Raises:
        ValueError: A bad origin or token, or a host beyond loopback without a token
            (and without ``allow_no_token``); the message says which in one line.
    """
    if isinstance(allow_origins, str):
        raise ValueError("allow_origins is a list of origins, not one string")
    allowed = {_origin_key(o) for o in APP_ORIGINS} | {
        _check_allowed_origin(o) for o in allow_origins
    }
    if token is not None:
        _check_token(token)
    elif not is_loopback(host) and not allow_no_token:
        raise ValueError(
            f"serving on {host!r} (beyond this computer) needs a token: anyone who "
            "reaches the port could drive the robot (or allow_no_token=True on a "
            "network whose every machine is trusted)"
        )
    return frozenset(allowed)


def _check_allowed_origin(origin: object) -> str:
    if not isinstance(origin, str) or not origin.strip():
        raise ValueError(f"an allowed origin must be a non-empty string, got {origin!r}")
    key = _origin_key(origin)
    if key == "null":
        # Sandboxed iframes and data: URLs of any site send "null": allowing it would
        # allow every page on the web.
        raise ValueError("the origin 'null' cannot be allowed: any page can send it")
    if key == "*":
        raise ValueError("'*' is not an origin; to allow any page, there is no option")
    parts = urlsplit(key)
    # Any scheme: a desktop app may send its own (app://..., as Electron apps can); the
    # refusal's log line shows what a refused app sent.
    if not parts.scheme or not parts.netloc or parts.path or parts.query or parts.fragment:
        raise ValueError(
            f"an allowed origin is scheme://host[:port] (as a browser sends it), got {origin!r}"
        )
    return key


def _check_token(token: object) -> str:
    if not isinstance(token, str):
        raise ValueError("token must be a string")
    if len(token) < MIN_TOKEN_LENGTH:
        raise ValueError(f"token must be at least {MIN_TOKEN_LENGTH} characters")
    if not all(33 <= ord(c) <= 126 for c in token):
        raise ValueError("token must be printable ASCII without spaces")
    return token


class FoxgloveServer:
    """One connected device, served live to the Foxglove app (see the module docstring).

    Use ``async with FoxgloveServer(robot) as server:`` inside ``async with robot:``;
    the address to open in the app is :attr:`url`.

    Args:
        device: A device (connected, or about to be: the server follows its link).
        host: Address to bind; ``127.0.0.1`` (default) serves this computer only.
        port: TCP port; 0 picks a free one (:attr:`port` says which).
        read_only: Take no velocity and offer only ``stop`` and ``emergency_stop``.
        record: Also record the session to this ``.mcap`` file, by
            :class:`~chassis_sdk.recording.McapRecording` (compressed, flushed every
            second: a hard kill loses at most the last second).
        name: The server's name, as the app shows it.
        allow_origins: ``Origin`` values let in besides no ``Origin`` and
            :data:`APP_ORIGINS` (``scheme://host[:port]``, e.g. a self-hosted Lichtblick).
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
                "serving to Foxglove needs foxglove-sdk and websockets: "
                "pip install 'chassis-sdk[foxglove]'"
            ) from None
        if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
            raise ValueError(f"port must be 0..65535, got {port!r}")
        self._allowed = check_access(
            host, allow_origins=allow_origins, token=token, allow_no_token=allow_no_token
        )
        self._token = token
        self._fg = foxglove
        self.device = device
        self.host = host
        self._port = port
        self.read_only = bool(read_only)
        self.record = Path(record) if record is not None else None
        if self.record is not None and self.record.suffix.lower() != ".mcap":
            raise ValueError(f"record must name a .mcap file, got {str(record)!r}")
        self.name = name or f"chassis-sdk {device.kind} {device.port}"
        #: Client messages refused (not a well-formed Twist, on a channel not taken,
        #: from a client that did not come through the front, or refused by the device).
        self.rejected = 0
        #: Errors caught in the server's callbacks (each also reported).
        self.errors = 0
        #: Connections refused at the handshake (a bad Origin, a missing or wrong token).
        self.refused_connections = 0
        #: Velocity commands taken from clients and handed to the device.
        self.commands = 0
        #: Velocity commands replaced by a newer one before they were handed over.
        self.superseded = 0
        self._context = foxglove.Context()
        self._sink: FoxgloveSink | None = None
        self._server: Any = None
        self._front: _Front | None = None
        self._recording: McapRecording | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        # Callbacks come from foxglove-sdk's threads, the front's and the event loop's.
        self._lock = threading.Lock()
        self._teleop: dict[tuple[int, int], str] = {}  # (client id, channel id) -> topic
        self._fronted: set[int] = set()  # client ids proven to come through the front
        self._secret = secrets.token_hex(16)
        # On stop, every interval is taken as passed, so the last refusals are logged.
        self._stopping = False
        self._reports = Refusals(REPORT_INTERVAL, clock=self._report_clock)
        self._handshake_reports = Refusals(REPORT_INTERVAL, clock=self._report_clock)
        # Velocity is state: the newest command not yet handed to the device, and
        # whether a hand-over is queued or running (then no other is queued).
        self._pending: tuple[float, float] | None = None
        self._driving = False
        # Set on leaving: no Twist is taken any more (the robot has been stopped).
        self._closing = False
        self._handing: asyncio.Future[None] | None = None  # the hand-over running

    def _report_clock(self) -> float:
        return math.inf if self._stopping else time.monotonic()

    @property
    def port(self) -> int:
        """The TCP port served (the one picked, for 0)."""
        return self._front.port if self._front is not None else self._port

    @property
    def url(self) -> str:
        """The address to open in the Foxglove app (without the token)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

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

        self._loop = asyncio.get_running_loop()
        # Fresh per-run state: the new server numbers its clients from 1 again, so a
        # client id proven (or driving) in the last run means nothing in this one.
        with self._lock:
            self._teleop = {}
            self._fronted = set()
            self._pending = None
            self._driving = False
            self._closing = False
        self._handing = None
        self._secret = secrets.token_hex(16)
        # Fresh reporters: the last stop() took every interval as passed.
        self._reports = Refusals(REPORT_INTERVAL, clock=self._report_clock)
        self._handshake_reports = Refusals(REPORT_INTERVAL, clock=self._report_clock)
        wanted = SAFE_SERVICES if self.read_only else SERVICES
        services = [self._service(n) for n in wanted if callable(getattr(self.device, n, None))]
        capabilities = [Capability.Services]
        if not self.read_only:
            capabilities.append(Capability.ClientPublish)
        listener = self._listener()

        def start_server(host: str) -> Any:
            return self._fg.start_server(
                name=self.name,
                host=host,
                port=0,  # private: only the front connects (see _private_loopback)
                capabilities=capabilities,
                supported_encodings=["json"],
                services=services,
                server_listener=listener,
                context=self._context,
            )

        backend_host = _private_loopback()
        try:
            self._server = start_server(backend_host)
        except RuntimeError:
            if backend_host == "127.0.0.1":
                raise
            backend_host = "127.0.0.1"  # a Linux whose loopback has only 127.0.0.1
            self._server = start_server(backend_host)
        front = _Front(self, f"ws://{backend_host}:{self._server.port}")
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
            ", ".join(sorted(self._allowed)),
            "required" if self._token is not None else "none",
        )

    async def aclose(self) -> None:
        """Stop serving without blocking the event loop (what ``async with`` does).

        If a Teleop client was driving, the robot is stopped first (zero velocity now,
        not at the deadman); the device goes on. Then the front and foxglove-sdk's
        server are shut down in worker threads, each waited for a bounded time.
        """
        if self._end_teleop() and not self.read_only:
            await self._stop_robot()
            handing = self._handing
            if handing is not None and not handing.done():
                # A velocity handed over just before may land after that zero: wait
                # for it (bounded), then zero again.
                with anyio.move_on_after(_FRONT_TIMEOUT), contextlib.suppress(Exception):
                    await asyncio.shield(handing)  # waited for, never cancelled
                await self._stop_robot()
        front, self._front = self._front, None
        server = self._server
        server_stopping = False
        try:
            if front is not None:
                front.signal_stop()
                await anyio.to_thread.run_sync(front.join, _FRONT_JOIN, abandon_on_cancel=True)
                self._flush_final()  # to the app, through the server still up
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

    async def _stop_robot(self) -> None:
        if not self.device.is_connected:
            return
        # A link that just dropped (or a stop that cannot be written at once) is no
        # reason to stay: the device's own deadman goes on meanwhile.
        with anyio.move_on_after(_FRONT_TIMEOUT), contextlib.suppress(ChassisError):
            await self.device.stop()

    def stop(self) -> None:
        """Stop serving, blocking until the front's thread ends (up to a few seconds
        with a client that does not read): from async code, ``await aclose()``.

        If a Teleop client was driving, a stop of the robot is queued in the loop."""
        if self._end_teleop() and not self.read_only:
            self._in_loop(self._stop_now)
        front, self._front = self._front, None
        if front is not None:
            front.signal_stop()
            front.join(_FRONT_JOIN)
            self._flush_final()
        server, self._server = self._server, None
        if server is not None:
            server.stop()
        self._release()

    def _end_teleop(self) -> bool:
        """Take no more Twists; whether a Teleop client was driving (or about to)."""
        with self._lock:
            self._closing = True
            driving = bool(self._teleop) or self._pending is not None or self._driving
            self._teleop.clear()
            self._pending = None
        return driving

    def _flush_final(self) -> None:
        self._stopping = True  # what is pending is reported now, not lost
        try:
            self._flush_reports()
        finally:
            self._stopping = False

    def _release(self) -> None:
        sink, self._sink = self._sink, None
        recording, self._recording = self._recording, None
        if recording is not None:
            recording.close()  # detaches its sink (the server's), then finishes the file
        elif sink is not None:
            sink.detach()

    # --- the handshake (the front's thread) ----------------------------------------------

    def _admit(self, headers: Any, path: str) -> tuple[http.HTTPStatus, str] | None:
        """``None`` to let a handshake in, else the HTTP status and the reason."""
        origins = headers.get_all("Origin")
        if len(origins) > 1:
            return http.HTTPStatus.FORBIDDEN, "more than one Origin header"
        if origins and _origin_key(origins[0]) not in self._allowed:
            shown = origins[0][:100]  # the peer's text: bounded, and shown as a repr
            return http.HTTPStatus.FORBIDDEN, f"Origin {shown!r} is not allowed"
        if self._token is not None:
            given = _given_tokens(headers, path)
            if len(given) != 1:
                why = "no token" if not given else "more than one token"
                return http.HTTPStatus.UNAUTHORIZED, why
            if not hmac.compare_digest(given[0].encode(), self._token.encode()):
                return http.HTTPStatus.UNAUTHORIZED, "a wrong token"
        return None

    def _refused_handshake(self, peer: str, why: str) -> None:
        with self._lock:
            self.refused_connections += 1
            report = self._handshake_reports.add(peer, why)
        if report is not None:
            self._send_handshake_report(report)

    def _send_handshake_report(self, report: RefusalReport) -> None:
        if report.count == 1:
            line = f"refused a connection from {report.where}: {report.why}"
        else:
            line = (
                f"refused {report.count} connections ({report.total} in all), "
                f"the latest from {report.where}: {report.why}"
            )
        _log.warning("%s", line)
        self._status(line, STATUS_HANDSHAKE)

    def _flush_reports(self) -> None:
        """Send what is pending (called every so often by the front)."""
        with self._lock:
            report = self._reports.due()
            handshakes = self._handshake_reports.due()
        if report is not None:
            self._send_report(report)
        if handshakes is not None:
            self._send_handshake_report(handshakes)

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
            handler=lambda request: self._called(method, request),
        )

    def _called(self, method: str, request: Any) -> bytes:
        try:
            if method not in SAFE_SERVICES and not self._is_fronted(request.client_id):
                # A stop is safe from anyone; what can let the robot move again is not.
                self._refuse(f"service {method}", "the client did not come through the front")
                ok, message = False, "refused: the connection was not checked"
            else:
                ok, message = self._run_in_loop(getattr(self.device, method))
                _log.info("service %s: %s", method, message)
        except Exception as exc:  # never let a service call fail unreported
            self._failed(f"service {method}", exc)
            ok, message = False, "internal error"
        return json.dumps({"success": ok, "message": message}).encode()

    def _run_in_loop(self, call: Callable[[], Coroutine[Any, Any, Any]]) -> tuple[bool, str]:
        loop = self._loop
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

    # --- client publishing (the server's threads) ----------------------------------------

    def _listener(self) -> Any:
        from foxglove.websocket import ServerListener

        server = self

        # Every callback is guarded: an exception escaping one is only logged by
        # foxglove-sdk ("Callback failed"), neither counted nor shown to the operator.
        class Listener(ServerListener):
            def on_client_advertise(self, client: Any, channel: Any) -> None:
                try:
                    server._advertised(client, channel)
                except Exception as exc:
                    server._failed("advertise", exc)

            def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
                try:
                    server._unadvertised(client, client_channel_id)
                except Exception as exc:
                    server._failed("unadvertise", exc)

            def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
                try:
                    server._message(client, client_channel_id, data)
                except Exception as exc:
                    server._failed("message", exc)

        return Listener()

    def _is_fronted(self, client_id: int) -> bool:
        with self._lock:
            return client_id in self._fronted

    def _advertised(self, client: Any, channel: Any) -> None:
        key = (client.id, channel.id)
        if channel.id == _HELLO_ID:
            topic = str(channel.topic)
            proof = topic.removeprefix(_HELLO_TOPIC)
            if topic.startswith(_HELLO_TOPIC) and hmac.compare_digest(
                proof.encode(), self._secret.encode()
            ):
                with self._lock:
                    self._fronted.add(client.id)
                return
            self._refuse(f"client {client.id}", "a channel on the front's reserved id")
            return
        is_twist = channel.schema_name in TWIST_SCHEMAS and channel.encoding == "json"
        if is_twist and not self._is_fronted(client.id):
            self._refuse(
                f"channel {_shown(channel.topic)}",
                "the client did not come through the front (Origin and token checks)",
            )
        elif is_twist:
            with self._lock:
                if self._closing:
                    return  # leaving: the robot has been stopped
                self._teleop[key] = _shown(channel.topic)
            _log.info("client %d drives on %s", client.id, _shown(channel.topic))
            return
        else:
            self._refuse(
                f"channel {_shown(channel.topic)}",
                f"{_shown(channel.schema_name)} ({_shown(channel.encoding)}) is not taken: "
                f"only JSON {TWIST_SCHEMAS[0]} drives",
            )
        self._drop_teleop(key)  # a Twist channel advertised again as anything else

    def _unadvertised(self, client: Any, client_channel_id: int) -> None:
        if client_channel_id == _HELLO_ID:
            with self._lock:
                self._fronted.discard(client.id)  # the connection is closing
        self._drop_teleop((client.id, client_channel_id))

    def _drop_teleop(self, key: tuple[int, int]) -> None:
        """The channel no longer drives: if it did, stop now, not at the deadman."""
        with self._lock:
            if self._teleop.pop(key, None) is None:
                return
            self._pending = None  # a command not yet handed over never will be
        self._in_loop(self._stop_now)

    def _message(self, client: Any, client_channel_id: int, data: bytes) -> None:
        with self._lock:
            topic = self._teleop.get((client.id, client_channel_id))
        if topic is None:
            self._refuse(f"channel {client_channel_id}", "a message on a channel not taken")
            return
        try:
            linear, angular = _twist(data)
        except CommandError as exc:
            self._refuse(f"velocity on {topic}", str(exc))
            return
        with self._lock:
            if self._closing or (client.id, client_channel_id) not in self._teleop:
                return  # leaving, or the channel went away meanwhile: it never drives
            if self._pending is not None:
                self.superseded += 1
            self._pending = (linear, angular)
            if self._driving:
                return  # the hand-over queued or running takes the newest when it runs
            self._driving = True
        self._in_loop(self._hand_over)

    def _in_loop(self, callback: Callable[[], None]) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop closed in between
                loop.call_soon_threadsafe(self._guarded, callback)

    def _guarded(self, callback: Callable[[], None]) -> None:
        try:
            callback()
        except Exception as exc:
            self._failed(getattr(callback, "__name__", "callback"), exc)

    # --- in the event loop ---------------------------------------------------------------

    def _hand_over(self) -> None:
        """Hand the newest pending velocity to the device: one at a time, so a flood of
        Twists never queues work in the loop (only the newest pending one counts)."""
        with self._lock:
            target = self._pending
            self._pending = None
            if target is None:
                self._driving = False
                return
        linear, angular = target
        task = asyncio.ensure_future(self.device.set_velocity(linear, angular))
        self._handing = task

        def done(task: asyncio.Future[None]) -> None:
            if not task.cancelled():
                exc = task.exception()
                if exc is None:
                    with self._lock:
                        self.commands += 1
                else:
                    self._refuse(f"velocity ({linear}, {angular})", f"refused: {exc}")
            self._guarded(self._hand_over)  # the next newest, if one came meanwhile

        task.add_done_callback(done)

    def _stop_now(self) -> None:
        if self.device.is_connected:
            asyncio.ensure_future(self.device.stop()).add_done_callback(_ignore_result)

    # --- reports ------------------------------------------------------------------------

    def _refuse(self, where: str, why: str) -> None:
        with self._lock:
            self.rejected += 1
            report = self._reports.add(where, why)
        if report is not None:
            self._send_report(report)

    def _failed(self, where: str, exc: BaseException) -> None:
        _log.error("%s failed", where, exc_info=exc)
        with self._lock:
            self.errors += 1
            report = self._reports.add(where, f"internal error: {type(exc).__name__}: {exc}")
        if report is not None:
            self._send_report(report)

    def _send_report(self, report: RefusalReport) -> None:
        line = report.summary()
        if report.count > 1:
            line += f" ({report.total} in all)"
        _log.warning("%s", line)
        self._status(line, STATUS_REFUSALS)

    def _status(self, message: str, kind: str) -> None:
        server = self._server
        if server is not None:
            from foxglove.websocket import StatusLevel

            with contextlib.suppress(Exception):  # the server is stopping
                server.publish_status(message[:1000], StatusLevel.Warning, id=kind)


def _shown(text: object, limit: int = 80) -> str:
    """A client's text as it goes into a log line or a status: bounded, and without
    quotes when it is plain (``/cmd_vel``), else as a repr (no control characters)."""
    value = str(text)
    short = value if len(value) <= limit else value[:limit] + "..."
    return short if short.isprintable() and " " not in short else repr(short)


def _given_tokens(headers: Any, path: str) -> list[str]:
    """The tokens a handshake carries: ``?token=`` and ``Authorization: Bearer``."""
    given = parse_qs(urlsplit(path).query, keep_blank_values=True).get("token", [])
    for value in headers.get_all("Authorization"):
        scheme, _, credentials = value.partition(" ")
        if scheme.lower() == "bearer":
            given.append(credentials.strip())
    return given


def _private_loopback() -> str:
    """A random address of 127.0.0.0/8 for foxglove-sdk's own server on Linux (every
    one of them is this computer's): a page that scans ports on 127.0.0.1 does not find
    it. Elsewhere 127.0.0.1 (macOS has only that one unless configured)."""
    if not sys.platform.startswith("linux"):
        return "127.0.0.1"
    return f"127.{secrets.randbelow(254) + 1}.{secrets.randbelow(256)}.{secrets.randbelow(254) + 1}"


def _ignore_result(task: asyncio.Future[None]) -> None:
    if not task.cancelled():
        task.exception()  # retrieved: a stop on a link that just dropped is no news


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


class _Front:
    """The WebSocket front: checks each handshake, then relays frames both ways
    between the client and foxglove-sdk's server, in a thread and event loop of its own
    (so the checking and copying never run in the application's loop)."""

    def __init__(self, server: FoxgloveServer, backend_url: str) -> None:
        self._server = server
        self._backend_url = backend_url
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stopping: anyio.Event | None = None
        self.port = 0
        # What the front sends first on each backend connection, when clients may
        # publish: a channel on the reserved id whose topic carries the secret.
        self._hello: str | None = None
        if not server.read_only:
            channel = {
                "id": _HELLO_ID,
                "topic": _HELLO_TOPIC + server._secret,
                "encoding": "json",
                "schemaName": "chassis_sdk.Front",
            }
            self._hello = json.dumps({"op": "advertise", "channels": [channel]})

    def start(self, host: str, port: int) -> None:
        self._thread = threading.Thread(
            target=self._run, args=(host, port), name="chassis-sdk-foxglove-front", daemon=True
        )
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._thread.join()
            raise RuntimeError(str(self._error)) from None

    def signal_stop(self) -> None:
        """Tell the front's loop to close (returns at once)."""
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stopping.set)

    def join(self, timeout: float) -> None:
        """Wait up to ``timeout`` for the front's thread to end (it closes within about
        :data:`_FRONT_TIMEOUT` of :meth:`signal_stop`, whatever the clients do)."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
            if thread.is_alive():
                _log.warning("the Foxglove front did not close within %g s", timeout)

    def _run(self, host: str, port: int) -> None:
        try:
            asyncio.run(self._main(host, port))
        except BaseException as exc:  # handed to start(), or logged
            if not self._ready.is_set():
                self._error = exc
                self._ready.set()
            else:
                _log.error("the Foxglove front failed", exc_info=exc)

    async def _main(self, host: str, port: int) -> None:
        from websockets.asyncio.server import serve

        self._loop = asyncio.get_running_loop()
        self._stopping = anyio.Event()
        try:
            front = await serve(
                self._relay,
                host,
                port,
                process_request=self._check,
                select_subprotocol=_select_subprotocol,
                compression=None,  # as foxglove-sdk's server: no permessage-deflate
                max_size=_MAX_CLIENT_FRAME,
                ping_interval=20,
                ping_timeout=20,
                # A handshake that never completes, or a closing client that does not
                # read, holds the front's shutdown this long at most.
                open_timeout=_FRONT_TIMEOUT,
                close_timeout=_FRONT_TIMEOUT,
                logger=_front_log,
            )
        except OSError as exc:
            raise RuntimeError(exc.strerror or str(exc)) from None
        async with front:
            self.port = int(front.sockets[0].getsockname()[1])
            self._ready.set()
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._flush_forever, name="chassis-sdk front reports")
                await self._stopping.wait()
                tg.cancel_scope.cancel()
            front.close(close_connections=True)

    async def _flush_forever(self) -> None:
        while True:
            await anyio.sleep(REPORT_INTERVAL / 2)
            try:
                self._server._flush_reports()
            except Exception as exc:
                _log.error("reporting refusals failed", exc_info=exc)

    def _check(self, connection: Any, request: Any) -> Any:
        refusal = self._server._admit(request.headers, request.path)
        if refusal is None:
            return None
        status, why = refusal
        peer = connection.remote_address
        where = f"{peer[0]}:{peer[1]}" if peer else "a client"
        self._server._refused_handshake(where, why)
        return connection.respond(status, f"{why}\n")

    async def _relay(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed

        try:
            backend = await connect(
                self._backend_url,
                subprotocols=[SUBPROTOCOL],  # type: ignore[list-item]
                compression=None,
                max_size=None,  # what the server sends is ours
                ping_interval=None,  # loopback: no keepalive needed
                open_timeout=5,
                close_timeout=_FRONT_TIMEOUT,
            )
        except Exception as exc:
            self._server._failed("connecting the front to the server", exc)
            await client.close(1011, "the server is not available")
            return
        try:
            if self._hello is not None:
                await backend.send(self._hello)

            async def relay(direction: Callable[[], Coroutine[Any, Any, None]]) -> None:
                try:
                    await direction()
                except ConnectionClosed:
                    pass
                except Exception as exc:
                    self._server._failed("relaying", exc)
                finally:
                    tg.cancel_scope.cancel()  # either direction ending ends the relay

            async with anyio.create_task_group() as tg:
                tg.start_soon(relay, functools.partial(self._up, client, backend))
                tg.start_soon(relay, functools.partial(_pump, backend, client))
        finally:
            # Closing the backend connection makes foxglove-sdk unadvertise the
            # client's channels: a Teleop that vanished stops the robot at once.
            await backend.close()

    async def _up(self, client: Any, backend: Any) -> None:
        """Client -> server: frames as they come, with channel ids kept honest."""
        advertised: dict[int, tuple[Any, Any, Any]] = {}
        async for frame in client:
            if isinstance(frame, str):
                for out in _rewrite(frame, advertised, self._server._refuse):
                    await backend.send(out)
            elif (
                len(frame) >= 5
                and frame[0] == _CLIENT_MESSAGE
                and (struct.unpack_from("<I", frame, 1)[0] == _HELLO_ID)
            ):
                self._server._refuse("a client", "a message on the front's reserved channel id")
            else:
                await backend.send(frame)


async def _pump(source: Any, sink: Any) -> None:
    async for frame in source:
        await sink.send(frame)


def _select_subprotocol(connection: Any, offered: Any) -> Any:
    from websockets.exceptions import NegotiationError

    if SUBPROTOCOL in offered:
        return SUBPROTOCOL
    # As foxglove-sdk's server itself: HTTP 400 without its subprotocol.
    raise NegotiationError(f"the subprotocol {SUBPROTOCOL} is required")


def _rewrite(
    frame: str,
    advertised: dict[int, tuple[Any, Any, Any]],
    refuse: Callable[[str, str], None],
) -> list[str]:
    """A client's text frame as the server should see it (nothing, if refused).

    A frame that is not a JSON object is refused (dropped and reported): every message
    of the protocol is one, and foxglove-sdk should not be the one to judge the rest.
    foxglove-sdk ignores an ``advertise`` of a channel id the client has already
    advertised, keeping the first schema: a channel re-advertised as ``std_msgs/String``
    would still be taken as a Twist. So an advertise that changes a channel's topic,
    encoding or schema goes as an ``unadvertise`` of the id, then the ``advertise``:
    the server's view follows the client's (and a Twist channel that changes stops the
    robot at once). One that changes nothing is dropped, as the server would ignore it.
    A new channel past :data:`MAX_CLIENT_CHANNELS` of the connection is refused. The
    front's reserved id is taken out. Any other JSON object goes unchanged.

    Args:
        frame: The text frame from the client.
        advertised: The connection's channels, by id, as (topic, encoding, schema
            name); updated.
        refuse: Called with where and why for what is refused.
    """
    try:
        msg = json.loads(frame)
    except RecursionError:
        refuse("a client's text frame", "not JSON: nested too deeply")
        return []
    except ValueError as exc:
        refuse("a client's text frame", f"not JSON: {_shown(exc, 60)}")
        return []
    if not isinstance(msg, dict):
        refuse("a client's text frame", f"not a JSON object but {type(msg).__name__}")
        return []
    op = msg.get("op")
    channels = msg.get("channels") if op == "advertise" else None
    if isinstance(channels, list) and all(isinstance(c, dict) for c in channels):
        out = []
        for channel in channels:
            cid = channel.get("id")
            if cid == _HELLO_ID:
                continue
            if isinstance(cid, int) and not isinstance(cid, bool):
                shape = (channel.get("topic"), channel.get("encoding"), channel.get("schemaName"))
                before = advertised.get(cid)
                if before == shape:
                    continue
                if before is None and len(advertised) >= MAX_CLIENT_CHANNELS:
                    refuse(
                        f"channel {_shown(channel.get('topic'))}",
                        f"more than {MAX_CLIENT_CHANNELS} channels on one connection",
                    )
                    continue
                if before is not None:
                    out.append(json.dumps({"op": "unadvertise", "channelIds": [cid]}))
                advertised[cid] = shape
            out.append(json.dumps({"op": "advertise", "channels": [channel]}))
        return out
    if op == "unadvertise" and isinstance(msg.get("channelIds"), list):
        ids = [i for i in msg["channelIds"] if i != _HELLO_ID]
        for cid in ids:
            if isinstance(cid, int) and not isinstance(cid, bool):
                advertised.pop(cid, None)
        return [json.dumps({"op": "unadvertise", "channelIds": ids})]
    return [frame]
