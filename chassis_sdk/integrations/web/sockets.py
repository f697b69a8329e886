"""The WebSocket of each page: who is let in (the page limit, and stop-only pages
beyond it), each page a source of the device's motion core, its messages read by the
per-page protocol (`Page.read`) and done, and the newest state sent to it (a page
that reads slowly gets fewer states, never a backlog).

``stop`` and ``estop`` are done as they arrive; a request (release, clear faults, LED,
buzzer) runs in a task of its own, one at a time per page, so a stop behind it never
waits. No message may end the server: each refusal is counted, logged (the first at
once, then at most one summary a second) and shown on the page.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable
from typing import Any

import anyio

from ...core.device import Device
from ...core.motion import MotionSource
from ...errors import ChassisError
from ..inbound import CommandError, Refusals
from .http import Access
from .page import MAX_MESSAGE, Drive, EStop, Page, Request, Stop, Terms, refusal_text
from .state import StateModel

__all__ = ["MAX_CLIENTS", "STOP_ONLY_PAGES", "PageSockets"]

_log = logging.getLogger("chassis_sdk.integrations.web")

#: The most WebSocket clients served at once (beyond them, `STOP_ONLY_PAGES`).
MAX_CLIENTS = 8
#: Pages let in beyond ``max_clients``, offered STOP and E-STOP only (more get HTTP
#: 503): pages that fill the limit (frozen tabs answer heartbeats) never keep the
#: operator from stopping the robot.
STOP_ONLY_PAGES = 2
#: Seconds between WebSocket pings: a client that does not answer within half of it is
#: closed (and, if it was driving, the robot stops).
_HEARTBEAT = 4.0
#: Seconds a request (release, clear faults, LED, buzzer) may take.
_REQUEST_TIMEOUT = 5.0


class _Client:
    """One WebSocket connection: its socket, its motion source, its side of the
    protocol, and the newest state not yet sent."""

    def __init__(self, ws: Any, source: MotionSource, page: Page) -> None:
        self.ws = ws
        #: Its source in the device's motion core (closed when the page goes away).
        self.source = source
        self.page = page
        self.name = source.name
        #: The newest state not yet sent, and whether the sender is waiting for one.
        self.state: str | None = None
        self.wake = asyncio.Event()
        self.busy = False


class PageSockets:
    """The pages of one dashboard (``/ws``).

    Args:
        web: ``aiohttp.web``.
        device: The device driven.
        terms: What every page is offered.
        access: The door every handshake passes.
        model: The state pages see (each open page is given its events).
        max_clients: The most pages served at once (then `STOP_ONLY_PAGES` more).
        on_error: Called for each error caught in a request.
    """

    def __init__(
        self,
        web: Any,
        device: Device[Any, Any],
        terms: Terms,
        access: Access,
        model: StateModel,
        max_clients: int,
        on_error: Callable[[], None],
    ) -> None:
        self._web = web
        self._device = device
        self._terms = terms
        self._access = access
        self._model = model
        self.max_clients = max_clients
        self._on_error = on_error
        self.clients: set[_Client] = set()
        #: Velocity commands taken by the motion core; messages refused.
        self.commands = 0
        self.refusals = Refusals()
        #: Set at the dashboard's close: no page let in, no drive message taken.
        self.closed = False
        #: Where requests run (the dashboard's task group, while it runs).
        self.tasks: anyio.abc.TaskGroup | None = None
        self._numbered = 0
        self._admitted = 0
        self._admitted_stop_only = 0

    async def socket(self, request: Any) -> Any:
        """The handler of ``/ws``: one page, from its handshake to its close."""
        web = self._web
        refused = self._access.check_socket(request)
        if refused is not None:
            return refused
        stop_only = self._admitted >= self.max_clients
        if self.closed or (stop_only and self._admitted_stop_only >= STOP_ONLY_PAGES):
            self._access.refuse(request, f"{self.max_clients} pages are connected already")
            return web.Response(status=503, text="too many pages connected\n")
        # Counted before the handshake's first await: the bound holds.
        if stop_only:
            self._admitted_stop_only += 1
        else:
            self._admitted += 1
        try:
            # aiohttp refuses a message of max_msg_size bytes or more: one byte more,
            # so that "at most 4 KiB" takes 4,096 bytes.
            ws = web.WebSocketResponse(
                heartbeat=_HEARTBEAT, max_msg_size=MAX_MESSAGE + 1, compress=False, autoping=True
            )
            await ws.prepare(request)
            self._numbered += 1
            source = self._device.motion.source(f"web page {self._numbered}", kind="web")
            client = _Client(ws, source, Page(source.name, self._terms, stop_only=stop_only))
            self.clients.add(client)
            self._model.pages.add(client.page)
            mode = " (stop only: the page limit is reached)" if stop_only else ""
            _log.info("web: %s connected from %s%s", client.name, request.remote, mode)
            try:
                model = self._model
                hello = client.page.hello(self._device.port, model.events, model.path)
                await ws.send_str(json.dumps(hello))
                async with anyio.create_task_group() as tg:
                    tg.start_soon(self._send, client)
                    await self._receive(client)
                    tg.cancel_scope.cancel()
            except (ConnectionError, RuntimeError):
                pass  # the page went away while its hello was written
            finally:
                self.clients.discard(client)
                self._model.pages.discard(client.page)
                if source.driving:
                    _log.info("web: %s left while driving; the robot is stopped", client.name)
                source.close()  # stops the robot only if this page was driving
                with anyio.CancelScope(shield=True), anyio.move_on_after(1.0):
                    await ws.close()
        finally:
            if stop_only:
                self._admitted_stop_only -= 1
            else:
                self._admitted -= 1
        return ws

    async def _send(self, client: _Client) -> None:
        """Send the newest state (a slow page gets fewer, never a backlog)."""
        ws = client.ws
        while True:
            await client.wake.wait()
            client.wake.clear()
            state, client.state = client.state, None
            if state is None:
                continue
            # The state is the same text for every page; its events are this page's.
            state = client.page.with_news(state)
            try:
                await ws.send_str(state)
            except (ConnectionError, RuntimeError):
                return  # the page went away: its receiving side sees the close

    async def _receive(self, client: _Client) -> None:
        aiohttp = self._web
        text_kind = aiohttp.WSMsgType.TEXT
        binary_kind = aiohttp.WSMsgType.BINARY
        async for message in client.ws:
            if message.type == binary_kind:
                self._refuse(client, "a binary message: commands are JSON text")
                continue
            if message.type != text_kind:
                break  # an error or a close: the socket is done
            try:
                await self._act(client, message.data.encode())
            except (CommandError, ValueError, TypeError) as exc:
                self._refuse(client, str(exc))
            except ChassisError as exc:
                self._refuse(client, f"not done: {exc}")
            except Exception as exc:  # no message may end the server
                _log.exception("web: error handling a message from %s", client.name)
                self._refuse(client, f"error: {type(exc).__name__}: {exc}")
            await anyio.lowlevel.checkpoint()  # a flood still lets the rest run

    def _refuse(self, client: _Client, why: str) -> None:
        report = self.refusals.add(client.name, why)
        client.page.refused(why, self.refusals.total)
        if report is not None:
            _log.warning("web: refused %s", report.summary())

    async def _act(self, client: _Client, raw: bytes) -> None:
        action = client.page.read(raw, time.monotonic())
        if isinstance(action, Drive):
            self._drive(client, action)
        elif isinstance(action, Stop):
            client.source.stop()
        elif isinstance(action, EStop):
            device: Any = self._device
            if not hasattr(device, "emergency_stop"):
                client.source.stop()
                client.page.done(f"E-STOP stopped the robot: a {device.device_name} has no e-stop")
                return
            await device.emergency_stop()
            client.page.done("estop")
        else:
            self._request(client, action)

    def _drive(self, client: _Client, drive: Drive) -> None:
        if self.closed:
            raise CommandError("the dashboard is closing")
        try:
            refusal = client.source.set_velocity(
                drive.linear, drive.angular, duration=self._terms.command_timeout, age=drive.age
            )
        except ChassisError as exc:  # not connected (an outage): this command is lost
            raise CommandError(f"not written: {exc}") from None
        if refusal is not None:
            raise CommandError(refusal_text(refusal))
        self.commands += 1

    def _request(self, client: _Client, request: Request) -> None:
        """Release, clear faults, LED, buzzer: in a task (a stop behind it never waits),
        one at a time per page."""
        device: Any = self._device
        kind = request.kind
        if kind in ("led", "buzzer"):
            call = getattr(device, f"set_{kind}")
            args: tuple[Any, ...] = (request.on,)
        else:
            call = device.release_emergency_stop if kind == "release" else device.clear_faults
            args = ()
        if client.busy:
            raise CommandError(f"{kind}: the previous request is not answered yet")
        if self.tasks is None:
            raise CommandError("the dashboard is not running")
        client.busy = True

        async def run() -> None:
            try:
                with anyio.fail_after(_REQUEST_TIMEOUT):
                    reported = await call(*args)
                if kind in ("led", "buzzer") and isinstance(reported, bool):
                    self._model.outputs[kind] = reported  # what the device says, every page
                client.page.done(kind)
            except (ChassisError, ValueError, TimeoutError) as exc:
                self._refuse(client, f"{kind} not done: {exc}")
            except Exception as exc:  # never the dashboard's end
                self._on_error()
                _log.exception("web: %s failed", kind)
                self._refuse(client, f"{kind} not done: {type(exc).__name__}")
            finally:
                client.busy = False

        self.tasks.start_soon(run, name=f"web {kind}")

    def send_all(self, state: str) -> None:
        """Give every page ``state`` (JSON text) as its newest."""
        for client in self.clients:
            client.state = state
            client.wake.set()

    def log_refusals(self) -> None:
        """Log the summary of refused messages, if one is due."""
        report = self.refusals.due()
        if report is not None:
            _log.warning("web: refused %s", report.summary())

    def closing(self) -> list[MotionSource]:
        """Take no more pages and no drive message; the sources of the pages driving."""
        self.closed = True
        return [c.source for c in self.clients if c.source.driving]

    async def close_all(self) -> None:
        """Close every page's socket (a second each at most)."""
        for client in list(self.clients):
            with contextlib.suppress(Exception), anyio.move_on_after(1.0):
                await client.ws.close(code=1001, message=b"server shutting down")
