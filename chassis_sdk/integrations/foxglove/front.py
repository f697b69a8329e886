"""Who may reach a [`FoxgloveServer`][chassis_sdk.integrations.foxglove.FoxgloveServer]: the
access options, the handshake's checks and the WebSocket front.

foxglove-sdk's server has no hook to look at a handshake, so it is bound to a private
loopback address (`private_loopback`) and port, and `Front` (on the
``websockets`` package, in a thread and event loop of its own) takes the connections on
the address asked for. `Gate` checks each handshake before anything reaches the
protocol: the ``Origin`` header (no ``Origin``, `APP_ORIGINS` and each
``allow_origins`` entry are let in, anything else gets HTTP 403) and, with a token, the
token (HTTP 401 without it). Then the front relays the frames both ways, keeping the
client's channel ids honest (`rewrite`), and proves each relayed connection to
the server with a secret, on a channel of its own (`HELLO_ID`). See the module
docstring of `chassis_sdk.integrations.foxglove` for why.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hmac
import http
import json
import logging
import re
import secrets
import struct
import sys
import threading
from collections.abc import Callable, Coroutine, Iterable
from typing import Any

import anyio

from ..access import (
    MIN_TOKEN_LENGTH,
    check_allowed_origin,
    check_token,
    given_tokens,
    is_loopback,
    origin_key,
)
from .reports import REPORT_INTERVAL, Reports, shown

__all__ = [
    "APP_ORIGINS",
    "FRONT_TIMEOUT",
    "HELLO_ID",
    "HELLO_TOPIC",
    "MAX_CLIENT_CHANNELS",
    "MIN_TOKEN_LENGTH",
    "SUBPROTOCOL",
    "Front",
    "Gate",
    "check_access",
    "is_loopback",
    "private_loopback",
    "rewrite",
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
#: ``Origin`` values let in without ``allow_origins``: the Foxglove web app (and its
#: former address), and ``file://``, which the Foxglove Studio and Lichtblick desktop
#: apps send (Electron pages loaded from files). Lichtblick's web app is self-hosted:
#: give its address with ``allow_origins``.
APP_ORIGINS = ("https://app.foxglove.dev", "https://studio.foxglove.dev", "file://")
#: The subprotocol spoken (the only one foxglove-sdk's server accepts).
SUBPROTOCOL = "foxglove.sdk.v1"
#: The client channel id the front uses for its proof; clients may not use it.
HELLO_ID = 0xFFFFFFFF
HELLO_TOPIC = "/_chassis_sdk/front/"
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
FRONT_TIMEOUT = 1.0


def check_access(
    host: str,
    *,
    allow_origins: Iterable[str] = (),
    token: str | None = None,
    allow_no_token: bool = False,
) -> frozenset[str]:
    """Check `FoxgloveServer`'s access options (as it does), before anything
    opens; return the origins let in.

    Raises:
        ValueError: A bad origin or token, or a host beyond loopback without a token
            (and without ``allow_no_token``); the message says which in one line.
    """
    if isinstance(allow_origins, str):
        raise ValueError("allow_origins is a list of origins, not one string")
    allowed = {origin_key(o) for o in APP_ORIGINS} | {
        check_allowed_origin(o) for o in allow_origins
    }
    if token is not None:
        check_token(token)
    elif not is_loopback(host) and not allow_no_token:
        raise ValueError(
            f"serving on {host!r} (beyond this computer) needs a token: anyone who "
            "reaches the port could drive the robot (or allow_no_token=True on a "
            "network whose every machine is trusted)"
        )
    return frozenset(allowed)


def private_loopback() -> str:
    """A random address of 127.0.0.0/8 for foxglove-sdk's own server on Linux (every
    one of them is this computer's): a page that scans ports on 127.0.0.1 does not find
    it. Elsewhere 127.0.0.1 (macOS has only that one unless configured)."""
    if not sys.platform.startswith("linux"):
        return "127.0.0.1"
    return f"127.{secrets.randbelow(254) + 1}.{secrets.randbelow(256)}.{secrets.randbelow(254) + 1}"


class Gate:
    """The handshake's checks: the ``Origin`` header, and the token if there is one.

    Args:
        allowed: The origins let in (from `check_access`), besides none.
        token: The token every client must give, or ``None``.
    """

    def __init__(self, allowed: frozenset[str], token: str | None) -> None:
        self.allowed = allowed
        self.token = token

    def admit(self, headers: Any, path: str) -> tuple[http.HTTPStatus, str] | None:
        """``None`` to let a handshake in, else the HTTP status and the reason."""
        origins = headers.get_all("Origin")
        if len(origins) > 1:
            return http.HTTPStatus.FORBIDDEN, "more than one Origin header"
        if origins and origin_key(origins[0]) not in self.allowed:
            shown = origins[0][:100]  # the peer's text: bounded, and shown as a repr
            return http.HTTPStatus.FORBIDDEN, f"Origin {shown!r} is not allowed"
        if self.token is not None:
            given = given_tokens(path, headers.get_all("Authorization"))
            if len(given) != 1:
                why = "no token" if not given else "more than one token"
                return http.HTTPStatus.UNAUTHORIZED, why
            if not hmac.compare_digest(given[0].encode(), self.token.encode()):
                return http.HTTPStatus.UNAUTHORIZED, "a wrong token"
        return None


class Front:
    """The WebSocket front: checks each handshake, then relays frames both ways
    between the client and foxglove-sdk's server, in a thread and event loop of its own
    (so the checking and copying never run in the application's loop).

    Args:
        backend_url: foxglove-sdk's server, on its private address.
        gate: The handshake's checks.
        reports: Where what is refused (or fails) is counted and reported.
        secret: The proof each relayed connection gives the server, when clients may
            publish (``None``: read-only, no proof is needed).
    """

    def __init__(
        self, backend_url: str, *, gate: Gate, reports: Reports, secret: str | None
    ) -> None:
        self._gate = gate
        self._reports = reports
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
        if secret is not None:
            channel = {
                "id": HELLO_ID,
                "topic": HELLO_TOPIC + secret,
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
        `FRONT_TIMEOUT` of `signal_stop`, whatever the clients do)."""
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
                open_timeout=FRONT_TIMEOUT,
                close_timeout=FRONT_TIMEOUT,
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
                self._reports.flush()
            except Exception as exc:
                _log.error("reporting refusals failed", exc_info=exc)

    def _check(self, connection: Any, request: Any) -> Any:
        refusal = self._gate.admit(request.headers, request.path)
        if refusal is None:
            return None
        status, why = refusal
        peer = connection.remote_address
        where = f"{peer[0]}:{peer[1]}" if peer else "a client"
        self._reports.refused_handshake(where, why)
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
                close_timeout=FRONT_TIMEOUT,
            )
        except Exception as exc:
            self._reports.failed("connecting the front to the server", exc)
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
                    self._reports.failed("relaying", exc)
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
                for out in rewrite(frame, advertised, self._reports.refuse):
                    await backend.send(out)
            elif (
                len(frame) >= 5
                and frame[0] == _CLIENT_MESSAGE
                and (struct.unpack_from("<I", frame, 1)[0] == HELLO_ID)
            ):
                self._reports.refuse("a client", "a message on the front's reserved channel id")
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


def rewrite(
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
    A new channel past `MAX_CLIENT_CHANNELS` of the connection is refused. The
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
        refuse("a client's text frame", f"not JSON: {shown(exc, 60)}")
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
            if cid == HELLO_ID:
                continue
            if isinstance(cid, int) and not isinstance(cid, bool):
                shape = (channel.get("topic"), channel.get("encoding"), channel.get("schemaName"))
                before = advertised.get(cid)
                if before == shape:
                    continue
                if before is None and len(advertised) >= MAX_CLIENT_CHANNELS:
                    refuse(
                        f"channel {shown(channel.get('topic'))}",
                        f"more than {MAX_CLIENT_CHANNELS} channels on one connection",
                    )
                    continue
                if before is not None:
                    out.append(json.dumps({"op": "unadvertise", "channelIds": [cid]}))
                advertised[cid] = shape
            out.append(json.dumps({"op": "advertise", "channels": [channel]}))
        return out
    if op == "unadvertise" and isinstance(msg.get("channelIds"), list):
        ids = [i for i in msg["channelIds"] if i != HELLO_ID]
        for cid in ids:
            if isinstance(cid, int) and not isinstance(cid, bool):
                advertised.pop(cid, None)
        return [json.dumps({"op": "unadvertise", "channelIds": ids})]
    return [frame]
