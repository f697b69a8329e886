"""A small client of the Foxglove WebSocket protocol, written from its specification
(github.com/foxglove/ws-protocol, docs/spec.md) on the ``websockets`` package: an
independent check of what ``chassis-sdk serve`` puts on the wire.

It offers both subprotocol names: ``foxglove.sdk.v1`` (what foxglove-sdk servers
accept) and ``foxglove.websocket.v1`` (the protocol's original name; same messages).
"""

from __future__ import annotations

import asyncio
import json
import struct
import time
from collections import defaultdict
from typing import Any
from urllib.parse import urlencode

import websockets
from websockets.typing import Origin, Subprotocol

SUBPROTOCOLS = [Subprotocol("foxglove.websocket.v1"), Subprotocol("foxglove.sdk.v1")]

# Binary opcodes.
_MESSAGE_DATA = 0x01  # server -> client: subscription id, receive time, payload
_CLIENT_MESSAGE = 0x01  # client -> server: client channel id, payload
_SERVICE_CALL = 0x02  # client -> server
_SERVICE_RESPONSE = 0x03  # server -> client


class FoxgloveClient:
    """Connects, records what the server advertises, subscribes, calls services and
    publishes on channels of its own."""

    def __init__(
        self,
        url: str,
        *,
        origin: str | None = None,
        token: str | None = None,
        bearer: str | None = None,
        subprotocols: list[str] | None = None,
    ) -> None:
        """``origin``: the ``Origin`` header to send (as a browser would; none by
        default, as a native client). ``token``: sent as the query parameter
        ``?token=``; ``bearer``: as ``Authorization: Bearer``."""
        self.url = url if token is None else f"{url}/?{urlencode({'token': token})}"
        self.origin = origin
        self.headers = {"Authorization": f"Bearer {bearer}"} if bearer is not None else {}
        self.offered = [Subprotocol(p) for p in subprotocols] if subprotocols else SUBPROTOCOLS
        self.server_info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}  # by topic
        self.services: dict[str, dict[str, Any]] = {}  # by name
        self.statuses: list[dict[str, Any]] = []
        self.received: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
        #: The same messages with the client's monotonic clock when each arrived.
        self.arrived: dict[str, list[tuple[float, bytes]]] = defaultdict(list)
        self._subs: dict[int, str] = {}
        self._next_sub = 1
        self._next_call = 1
        self._calls: dict[int, asyncio.Future[bytes]] = {}
        self._arrived = asyncio.Event()
        self._ws: Any = None
        self._reader: asyncio.Task[None] | None = None

    async def __aenter__(self) -> FoxgloveClient:
        self._ws = await websockets.connect(
            self.url,
            subprotocols=self.offered,
            origin=Origin(self.origin) if self.origin is not None else None,
            additional_headers=self.headers,
        )
        self._reader = asyncio.create_task(self._read())
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self._ws.close()
        if self._reader is not None:
            self._reader.cancel()

    @property
    def subprotocol(self) -> str:
        return str(self._ws.subprotocol)

    async def _read(self) -> None:
        async for frame in self._ws:
            if isinstance(frame, str):
                self._on_text(json.loads(frame))
            elif frame[0] == _MESSAGE_DATA:
                sub, ts = struct.unpack_from("<IQ", frame, 1)
                self.received[self._subs[sub]].append((ts, bytes(frame[13:])))
                self.arrived[self._subs[sub]].append((time.monotonic(), bytes(frame[13:])))
            elif frame[0] == _SERVICE_RESPONSE:
                _, call, n = struct.unpack_from("<III", frame, 1)
                future = self._calls.pop(call)
                if not future.done():
                    future.set_result(bytes(frame[13 + n :]))
            self._arrived.set()

    def _on_text(self, msg: dict[str, Any]) -> None:
        op = msg["op"]
        if op == "serverInfo":
            self.server_info = msg
        elif op == "advertise":
            for channel in msg["channels"]:
                self.channels[channel["topic"]] = channel
        elif op == "advertiseServices":
            for service in msg["services"]:
                self.services[service["name"]] = service
        elif op == "status":
            self.statuses.append(msg)
        elif op == "serviceCallFailure":
            future = self._calls.pop(msg["callId"])
            if not future.done():
                future.set_exception(RuntimeError(msg["message"]))

    async def wait_for(self, predicate: Any, timeout: float = 5.0) -> None:
        """Wait until ``predicate()`` holds (checked whenever something arrives)."""

        async def loop() -> None:
            while not predicate():
                self._arrived.clear()
                await self._arrived.wait()

        await asyncio.wait_for(loop(), timeout)

    async def subscribe(self, *topics: str) -> None:
        # Only channels advertised (the advertise follows serverInfo, as above).
        await self.wait_for(lambda: all(topic in self.channels for topic in topics))
        subs = []
        for topic in topics:
            sub = self._next_sub
            self._next_sub += 1
            self._subs[sub] = topic
            subs.append({"id": sub, "channelId": self.channels[topic]["id"]})
        await self._ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def call(self, service: str, request: bytes = b"{}", timeout: float = 5.0) -> Any:
        # As a real client, only once the service is advertised: the server sends its
        # advertiseServices after serverInfo, so a caller that waited for serverInfo
        # alone may be here first (it was, once, on uvloop).
        await self.wait_for(lambda: service in self.services, timeout)
        spec = self.services[service]
        call = self._next_call
        self._next_call += 1
        future: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        self._calls[call] = future
        encoding = b"json"
        header = struct.pack("<BIII", _SERVICE_CALL, spec["id"], call, len(encoding))
        await self._ws.send(header + encoding + request)
        return json.loads(await asyncio.wait_for(future, timeout))

    async def advertise(
        self, channel_id: int, topic: str, schema_name: str, encoding: str = "json"
    ) -> None:
        channel = {
            "id": channel_id,
            "topic": topic,
            "encoding": encoding,
            "schemaName": schema_name,
        }
        await self._ws.send(json.dumps({"op": "advertise", "channels": [channel]}))

    async def unadvertise(self, channel_id: int) -> None:
        await self._ws.send(json.dumps({"op": "unadvertise", "channelIds": [channel_id]}))

    async def publish(self, channel_id: int, payload: bytes) -> None:
        await self._ws.send(struct.pack("<BI", _CLIENT_MESSAGE, channel_id) + payload)

    async def send_raw(self, frame: str | bytes) -> None:
        """Send a frame as it is (text or binary), whatever it holds."""
        await self._ws.send(frame)

    def abort(self) -> None:
        """Vanish as a crashed client or a dropped network does: no closing handshake."""
        self._ws.transport.abort()

    def messages(self, topic: str) -> list[Any]:
        return [json.loads(data) for _, data in self.received[topic]]
