"""The web dashboard: one device, watched and driven by hand from a browser.

`WebDashboard` serves one page (``static/``: HTML, JavaScript, CSS and the
uPlot charting library, all in the package; nothing is built or fetched) and a
WebSocket at ``/ws`` on an aiohttp server. The page shows the device live (speeds
commanded beside measured, wheels, battery, status and faults, events, the link and the
age of its last frame, the odometry path; a board's IMU, LED and buzzer) and drives it
from an on-screen joystick, the keyboard or a gamepad.

What it shows comes by callback (``chassis_sdk.core.Notifier(device).listen``): each
reading is kept as it arrives, inside the device's read path, with no task per stream;
the newest of each stream goes to every page ``rate`` times a second, and a page that
reads slowly gets fewer states, never a backlog (memory stays bounded: one state, the
events and notes not yet sent, per page).

Driving: one contract with every other surface
----------------------------------------------
Each page is a source of the device's motion core (``device.motion.source("web page
N", kind="web")``), made when it connects and closed when it goes away; the rules are
the core's, the same for every surface:

* Each ``drive`` message is one fresh ``set_velocity(linear, angular,
  duration=command_timeout)`` of that page's source: the page sends the current
  command at 20 Hz while a control is held, so a frozen tab, a lost network or a closed
  laptop stops the robot within ``command_timeout``. Releasing a control sends ``stop``
  at once; the page hidden sends ``stop``; a socket that closes (or misses its
  heartbeat) while its page was driving stops the robot at once (a page that did not
  drive leaves the robot to the one that does).
* One page drives at a time: another page's velocity is refused ("driven by web page
  1") until the driving page's command lapses or it stops. A block (an e-stop of any
  origin, a bumper, a fault, a lost link) refuses velocity and ends the command; after
  it a page must send a zero or a stop before it drives again (the page's script
  sends its stop right after its E-STOP: it has let go of its controls).
* Velocity is state, not a queue: the core writes at most one velocity frame per
  `~chassis_sdk.core.motion.WRITE_PERIOD`, the newest. ``stop`` and ``estop`` are
  acted on as they arrive, never behind a velocity or a request, and a velocity taken
  before a stop is never written after it.
* A drive message carries the page's clock (``t``, milliseconds of
  ``performance.now()``). The server keeps, per connection, the least difference
  between its own clock and the page's (the fastest a message has come); a message
  that arrives later than that by more than ``command_timeout`` was held up (a stalled
  network delivering a backlog) and is refused; a later one is given to the core that
  much old (its deadman counts from then). No clock needs to agree with another.
* A message that is not a well-formed command (not JSON, UTF-8 only, duplicate keys,
  unknown type or keys, wrong types, non-finite, beyond ``max_linear``/``max_angular``)
  is refused, counted, logged (the first at once, then at most one summary a second,
  by `Refusals`) and shown on the page; it
  never moves the robot and never ends the server.
* ``read_only``: the page offers only STOP and E-STOP, and the server takes nothing
  else; the device writes nothing at close that no page asked for.
* With ``max_clients`` pages connected, a few more (`STOP_ONLY_PAGES`) are let in
  behind the same checks offering only STOP and E-STOP: the operator can always stop.

Who may connect
---------------
Loopback by default. Then only requests whose ``Host`` names this computer are served
(a page elsewhere that rebinds its own name to 127.0.0.1 gets HTTP 403). Beyond
loopback a token is required (a random one unless given): the URL to open carries it
once (``/?token=...``, as Jupyter does), the server answers with a cookie for this
port (``HttpOnly``, ``SameSite=Lax``: sent when the operator follows the address from
another site, never with another site's requests) and sends the browser on to ``/``. Every
request but the static files needs the token (the cookie, ``?token=`` or
``Authorization: Bearer``), compared in constant time. The WebSocket handshake's
``Origin`` must be the page's own (``http://`` + the ``Host`` asked for) or one of
``allow_origins``: another page in the operator's browser cannot drive. The page
cannot be framed (``frame-ancestors 'none'``) and loads nothing from elsewhere. A
refused request or handshake is counted (`refused_connections`) and logged as the
refused messages are: the first at once, then at most one summary a second.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import math
import secrets
import time
from collections import deque
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from importlib import resources
from types import TracebackType
from typing import Any, Self
from urllib.parse import urlsplit

import anyio

from ...core.charge import battery_fields
from ...core.device import Device
from ...core.motion import MotionSource, Refusal
from ...core.notifier import Notifier
from ...core.plain import outbound
from ...core.validation import check_int, check_real
from ...devices import profile
from ...errors import ChassisError
from ..access import check_allowed_origin, check_token, given_tokens, is_loopback, origin_key
from ..inbound import CommandError, RefusalReport, Refusals, command_number, command_object

__all__ = [
    "DEFAULT_MAX_ANGULAR",
    "DEFAULT_MAX_LINEAR",
    "MAX_CLIENTS",
    "MAX_DEADZONE",
    "STOP_ONLY_PAGES",
    "GamepadMapping",
    "WebDashboard",
]

_log = logging.getLogger("chassis_sdk.integrations.web")

#: The widest gamepad deadzone taken (a fraction of full deflection).
MAX_DEADZONE = 0.95
#: What a page may ask for when neither the dashboard nor the device sets a limit
#: (m/s, rad/s): ``chassis-sdk drive``'s defaults, slow enough to walk beside.
DEFAULT_MAX_LINEAR = 0.5
DEFAULT_MAX_ANGULAR = 1.0
#: The most WebSocket clients served at once (beyond them, `STOP_ONLY_PAGES`).
MAX_CLIENTS = 8
#: Pages let in beyond ``max_clients``, offered STOP and E-STOP only (more get HTTP
#: 503): pages that fill the limit (frozen tabs answer heartbeats) never keep the
#: operator from stopping the robot.
STOP_ONLY_PAGES = 2
#: The largest WebSocket message taken (a drive message is about 60 bytes).
_MAX_MESSAGE = 4096
#: Seconds between WebSocket pings: a client that does not answer within half of it is
#: closed (and, if it was driving, the robot stops).
_HEARTBEAT = 4.0
#: Seconds an idle HTTP connection is kept open.
_KEEPALIVE = 10.0
#: Events kept for a page that opens later, and odometry path points.
_EVENTS_KEPT = 50
_PATH_POINTS = 2000
#: Least distance (m) between two points of the path kept.
_PATH_STEP = 0.02
#: Seconds a request (release, clear faults, LED, buzzer) may take.
_REQUEST_TIMEOUT = 5.0
_STATIC = {
    "app.js": "text/javascript",
    "app.css": "text/css",
    "uPlot.iife.min.js": "text/javascript",
    "uPlot.min.css": "text/css",
}
_SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; connect-src 'self'; img-src 'self' data:; "
        "style-src 'self'; script-src 'self'; frame-ancestors 'none'; base-uri 'none'; "
        "form-action 'none'"
    ),
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


@dataclass(frozen=True, slots=True)
class GamepadMapping:
    """How the page reads a gamepad (the browser's Gamepad API, standard mapping), as
    teleop_twist_joy's parameters.

    Attributes:
        linear_axis: The axis for linear speed (``axes[1]``: the left stick's vertical;
            up is negative in the API, so it is inverted).
        angular_axis: The axis for turning (``axes[0]``: the left stick's horizontal;
            left turns counter-clockwise).
        enable_button: The button held to drive (``buttons[4]``: LB); released, the
            robot stops at once.
        scale_linear: Full deflection, as a fraction of ``max_linear``.
        scale_angular: Full deflection, as a fraction of ``max_angular``.
        deadzone: Deflections below it count as none.
        stale_after: Seconds without a new reading from the pad (its ``timestamp``
            unchanged) after which, while enabled, it counts as gone: the robot stops.
    """

    linear_axis: int = 1
    angular_axis: int = 0
    enable_button: int = 4
    scale_linear: float = 1.0
    scale_angular: float = 1.0
    deadzone: float = 0.1
    stale_after: float = 1.0

    def __post_init__(self) -> None:
        for name in ("linear_axis", "angular_axis", "enable_button"):
            check_int(getattr(self, name), name, low=0, high=63)
        for name in ("scale_linear", "scale_angular"):
            check_real(getattr(self, name), name, low=0, low_open=True, high=1)
        check_real(self.deadzone, "deadzone", low=0, high=MAX_DEADZONE)
        check_real(self.stale_after, "stale_after", low=0, low_open=True, high=10, unit="s")


def _limit(name: str, given: float | None, device: float | None, default: float) -> float:
    if given is None:
        return device if device is not None else default
    limit = check_real(given, name, low=0, low_open=True)
    return limit if device is None else min(limit, device)


def _keys(body: Mapping[str, Any], allowed: Iterable[str]) -> None:
    extra = set(body) - {"type", *allowed}
    if extra:
        raise CommandError(f"unknown keys {sorted(extra)!r} for {body['type']!r}")


class _Client:
    """One WebSocket connection: its socket, its motion source, its clock and what it
    is doing."""

    def __init__(self, ws: Any, source: MotionSource, actions: list[str], stop_only: bool) -> None:
        self.ws = ws
        #: Its source in the device's motion core (closed when the page goes away).
        self.source = source
        self.name = source.name
        #: What this page may do (a stop-only page, let in beyond the limit: STOP and
        #: E-STOP).
        self.actions = actions
        self.stop_only = stop_only
        #: The least (server clock - page clock) seen: the fastest delivery.
        self.offset = math.inf
        self.last_t = -math.inf
        #: The newest state not yet sent, and whether the sender is waiting for one.
        self.state: str | None = None
        self.wake = asyncio.Event()
        self.events: deque[dict[str, Any]] = deque(maxlen=_EVENTS_KEPT)
        self.notes: deque[dict[str, Any]] = deque(maxlen=32)
        self.busy = False


class WebDashboard:
    """One connected device, served to browsers (see the module docstring).

    Use ``async with WebDashboard(robot) as web:`` inside ``async with robot:``; the
    address to open is [`login_url`][chassis_sdk.integrations.web.WebDashboard.login_url].

    Args:
        device: A device (connected, or about to be: the page follows its link).
        host: Address to bind; ``127.0.0.1`` (default) serves this computer only.
        port: TCP port; 0 picks a free one (`port` says which).
        read_only: Take no velocity and no request: the page offers STOP and E-STOP only
            (and ``device.motion.zero_on_close`` is set False: the device's close writes
            no zero unless a page stopped it).
        token: The secret every request must carry (at least 16 printable ASCII
            characters). Beyond loopback a random one is made if none is given; on
            loopback none is needed unless given.
        allow_origins: WebSocket ``Origin`` values let in besides the page's own
            (``scheme://host[:port]``: a page of yours that embeds the dashboard's data).
        command_timeout: The deadman of each drive message (default: the device's,
            else 0.5 s).
        max_linear: The fastest a page may ask for (m/s): the joystick's full
            deflection; more is refused. Default: the device's limit, else
            `DEFAULT_MAX_LINEAR` (slow enough to walk beside).
        max_angular: The same for turning (rad/s); default the device's limit, else
            `DEFAULT_MAX_ANGULAR`.
        rate: State updates a second sent to each page (1 to 50).
        gamepad: How the page reads a gamepad.
        max_clients: The most pages served at once; beyond them `STOP_ONLY_PAGES` more
            are let in offering STOP and E-STOP only.

    Raises:
        ValueError: A bad option (before anything opens).
    """

    def __init__(
        self,
        device: Device[Any, Any],
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        read_only: bool = False,
        token: str | None = None,
        allow_origins: Iterable[str] = (),
        command_timeout: float | None = None,
        rate: float = 20.0,
        gamepad: GamepadMapping | None = None,
        max_clients: int = MAX_CLIENTS,
        max_linear: float | None = None,
        max_angular: float | None = None,
    ) -> None:
        try:
            from aiohttp import web
        except ImportError:
            raise ImportError(
                "the web dashboard needs aiohttp: pip install 'chassis-sdk[web]'"
            ) from None
        self._web = web
        if not isinstance(host, str) or not host:
            raise ValueError(f"host must be an address, got {host!r}")
        check_int(port, "port", low=0, high=65535)
        if isinstance(allow_origins, str):
            raise ValueError("allow_origins is a list of origins, not one string")
        self._origins = frozenset(check_allowed_origin(o) for o in allow_origins)
        if token is not None:
            check_token(token)
        elif not is_loopback(host):
            token = secrets.token_urlsafe(24)
        self._token = token
        timeout = command_timeout if command_timeout is not None else device.command_timeout
        timeout = 0.5 if timeout is None else timeout
        timeout = check_real(timeout, "command_timeout", low=0, low_open=True, unit="s")
        check_real(rate, "rate", low=1, high=50, unit="updates a second")
        check_int(max_clients, "max_clients", low=1)
        limits = device.limits
        self.max_linear = _limit("max_linear", max_linear, limits.max_linear, DEFAULT_MAX_LINEAR)
        self.max_angular = _limit(
            "max_angular", max_angular, limits.max_angular, DEFAULT_MAX_ANGULAR
        )
        self.device = device
        self.host = host
        self._port = port
        self.read_only = bool(read_only)
        self.command_timeout = timeout
        self.rate = float(rate)
        self.gamepad = gamepad if gamepad is not None else GamepadMapping()
        self.max_clients = max_clients
        self._profile = profile(device.device_name)
        self._actions = self._offered()
        #: Velocity commands taken by the motion core; requests and handshakes refused
        #: at the door.
        self.commands = 0
        self.refused_connections = 0
        self.refusals = Refusals()
        self._door = Refusals()
        self._clients: set[_Client] = set()
        self._numbered = 0
        self._admitted = 0
        self._admitted_stop_only = 0
        #: Errors caught in the dashboard's own tasks and callbacks (logged with their
        #: traceback: each of a task, the first of each callback).
        self.errors = 0
        self._events: deque[dict[str, Any]] = deque(maxlen=_EVENTS_KEPT)
        self._path: deque[tuple[float, float]] = deque(maxlen=_PATH_POINTS)
        self._latest: dict[str, Any] = {}
        self._runner: Any = None
        self._bound = 0
        self._tasks: anyio.abc.TaskGroup | None = None
        self._background: asyncio.Task[None] | None = None
        self._notifier: Notifier | None = None
        self._closed = False

    # --- what it is --------------------------------------------------------------------

    @property
    def refused(self) -> int:
        """Messages refused since the start."""
        return self.refusals.total

    @property
    def clients(self) -> int:
        """Pages connected now."""
        return len(self._clients)

    @property
    def token(self) -> str | None:
        """The token required (the one made, beyond loopback), or ``None``."""
        return self._token

    @property
    def port(self) -> int:
        """The TCP port served (the one picked, for 0)."""
        return self._bound or self._port

    @property
    def url(self) -> str:
        """The page's address, without the token."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        if host in ("0.0.0.0", "[::]"):
            host = "127.0.0.1" if host == "0.0.0.0" else "[::1]"
        return f"http://{host}:{self.port}/"

    @property
    def login_url(self) -> str:
        """The address to open once: `url` with the token, when one is required."""
        return self.url if self._token is None else f"{self.url}?token={self._token}"

    def _offered(self) -> list[str]:
        """The actions the page offers, by what the device has and the mode."""
        device: Any = self.device
        actions = ["stop", "estop"]  # without an e-stop, E-STOP stops
        if self.read_only:
            return actions
        actions.append("drive")
        if hasattr(device, "release_emergency_stop"):
            actions.append("release")
        if hasattr(device, "clear_faults"):
            actions.append("clear_faults")
        features = self._profile.remote.features
        for name in ("led", "buzzer"):
            if features.get(name) and hasattr(device, f"set_{name}"):
                actions.append(name)
        return actions

    # --- lifetime ----------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()

    async def start(self) -> None:
        """Bind and start serving (and watching the device).

        Raises:
            ChassisError: The address cannot be bound (in use, not this computer's).
        """
        web = self._web
        # An idle connection is closed after _KEEPALIVE (aiohttp's default is an hour:
        # anyone who reaches the port could hold descriptors the device needs).
        app = web.Application(
            client_max_size=_MAX_MESSAGE,
            handler_args={"max_field_size": 8190, "keepalive_timeout": _KEEPALIVE},
        )
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._socket)
        app.router.add_get("/static/{name}", self._static)
        app.on_response_prepare.append(self._secure)
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self._port, reuse_address=True)
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise ChassisError(
                f"cannot serve on {self.host}:{self._port}: {exc.strerror or exc}"
            ) from None
        self._runner = runner
        if self.read_only:
            # Nothing written at close that no page asked for (a page's STOP is written,
            # and then the close's zero too).
            self.device.motion.zero_on_close = False
        if runner.addresses:
            self._bound = runner.addresses[0][1]
        self._notifier = self._listen()
        # The dashboard's own tasks live in a task of their own, not in the caller's:
        # nothing of theirs can cancel the application around the dashboard.
        self._background = asyncio.get_running_loop().create_task(
            self._run_tasks(), name="web dashboard"
        )

    async def _run_tasks(self) -> None:
        async with anyio.create_task_group() as tg:
            self._tasks = tg
            # None of them may end the dashboard: each is guarded.
            tg.start_soon(self._guarded, "the state broadcast", self._broadcast)

    async def _guarded(self, what: str, job: Callable[..., Awaitable[None]], *args: Any) -> None:
        """Run ``job``; a link lost for good (a device without ``reconnect``) ends it
        quietly (the page shows the link), any other error is logged and counted."""
        try:
            await job(*args)
        except ChassisError as exc:
            _log.info("web: %s ended: %s", what, exc)
        except Exception:
            self.errors += 1
            _log.exception("web: %s failed; the dashboard goes on without it", what)

    async def aclose(self) -> None:
        """Stop the robot if a page was driving it, close every page, stop serving.

        From its first line no drive message is taken and none is written: the pages
        still open while they are closed cannot move the robot after its zero.
        """
        if self._closed:
            return
        self._closed = True
        driving = [c for c in self._clients if c.source.driving]
        if self._notifier is not None:
            self._notifier.close()  # no more readings kept
        background = self._background
        if background is not None:
            background.cancel()  # the broadcast, the requests
        for client in driving:
            with contextlib.suppress(ChassisError):
                client.source.stop()
        with anyio.CancelScope(shield=True):
            for client in list(self._clients):
                with contextlib.suppress(Exception), anyio.move_on_after(1.0):
                    await client.ws.close(code=1001, message=b"server shutting down")
            if self._runner is not None:
                with anyio.move_on_after(2.0):
                    await self._runner.cleanup()
            if background is not None:
                await asyncio.wait([background])  # (its cancellation is not ours)

    # --- HTTP --------------------------------------------------------------------------

    async def _secure(self, request: Any, response: Any) -> None:
        for name, value in _SECURITY_HEADERS.items():
            response.headers.setdefault(name, value)

    def _cookie(self) -> str:
        return f"chassis_sdk_token_{self.port}"

    def _refuse_request(self, request: Any) -> Any:
        """The HTTP error for a request that may not be served, else ``None``."""
        web = self._web
        # The header itself: aiohttp's request.host falls back to a blocking
        # socket.getfqdn() in some versions when there is none.
        host_header = request.headers.get("Host")
        if not host_header:
            self._refused_at_door(request, "no Host header")
            return web.Response(status=400, text="no Host header\n")
        if is_loopback(self.host):
            try:
                host = urlsplit(f"//{host_header}").hostname or ""
            except ValueError:
                host = ""
            if not is_loopback(host):
                self._refused_at_door(request, f"Host {host_header[:100]!r} is not this computer")
                return web.Response(status=403, text="Host is not this computer\n")
        if self._token is None:
            return None
        given = given_tokens(request.path_qs, request.headers.getall("Authorization", []))
        cookie = request.cookies.get(self._cookie())
        if cookie is not None:
            given.append(cookie)
        if not any(hmac.compare_digest(g.encode(), self._token.encode()) for g in given):
            self._refused_at_door(request, "no token" if not given else "a wrong token")
            return web.Response(
                status=401,
                text="open the address chassis-sdk web printed (it carries ?token=...)\n",
            )
        return None

    def _refused_at_door(self, request: Any, why: str) -> None:
        """Count a refused request; log the first at once, then a summary a second."""
        self.refused_connections += 1
        _log_door(self._door.add(request.remote or "?", why))

    async def _index(self, request: Any) -> Any:
        web = self._web
        refused = self._refuse_request(request)
        if refused is not None:
            return refused
        if self._token is not None and "token" in request.query:
            # The token leaves the address bar (and the history) for a cookie.
            redirect = web.HTTPSeeOther("/")
            redirect.set_cookie(
                self._cookie(), self._token, httponly=True, samesite="Lax", path="/"
            )
            raise redirect
        page = resources.files(__package__).joinpath("static/index.html").read_text("utf-8")
        return web.Response(text=page, content_type="text/html", charset="utf-8")

    async def _static(self, request: Any) -> Any:
        web = self._web
        name = request.match_info["name"]
        kind = _STATIC.get(name)
        if kind is None:
            raise web.HTTPNotFound()
        body = resources.files(__package__).joinpath(f"static/{name}").read_bytes()
        return web.Response(body=body, content_type=kind, charset="utf-8")

    # --- WebSocket ---------------------------------------------------------------------

    def _origin_refused(self, request: Any) -> str | None:
        origins = request.headers.getall("Origin", [])
        if len(origins) > 1:
            return "more than one Origin header"
        if not origins:
            return None  # not a browser: the token (if any) was checked
        origin = origin_key(origins[0])
        host = request.headers.get("Host", "")
        own = {origin_key(f"{scheme}://{host}") for scheme in ("http", "https")}
        if origin in own or origin in self._origins:
            return None
        return f"Origin {origins[0][:100]!r} is not allowed"

    async def _socket(self, request: Any) -> Any:
        web = self._web
        refused = self._refuse_request(request)
        if refused is not None:
            return refused
        why = self._origin_refused(request)
        if why is not None:
            self._refused_at_door(request, why)
            return web.Response(status=403, text=f"{why}\n")
        stop_only = self._admitted >= self.max_clients
        if self._closed or (stop_only and self._admitted_stop_only >= STOP_ONLY_PAGES):
            self._refused_at_door(request, f"{self.max_clients} pages are connected already")
            return web.Response(status=503, text="too many pages connected\n")
        # Counted before the handshake's first await: the bound holds.
        if stop_only:
            self._admitted_stop_only += 1
        else:
            self._admitted += 1
        try:
            ws = web.WebSocketResponse(
                heartbeat=_HEARTBEAT, max_msg_size=_MAX_MESSAGE, compress=False, autoping=True
            )
            await ws.prepare(request)
            self._numbered += 1
            source = self.device.motion.source(f"web page {self._numbered}", kind="web")
            actions = ["stop", "estop"] if stop_only else self._actions
            client = _Client(ws, source, actions, stop_only)
            self._clients.add(client)
            mode = " (stop only: the page limit is reached)" if stop_only else ""
            _log.info("web: %s connected from %s%s", client.name, request.remote, mode)
            try:
                await ws.send_str(json.dumps(self._hello(client)))
                async with anyio.create_task_group() as tg:
                    tg.start_soon(self._send, client)
                    await self._receive(client)
                    tg.cancel_scope.cancel()
            except (ConnectionError, RuntimeError):
                pass  # the page went away while its hello was written
            finally:
                self._clients.discard(client)
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

    def _hello(self, client: _Client) -> dict[str, Any]:
        device = self.device
        stop_only = client.stop_only
        return {
            "type": "hello",
            "device": device.device_name,
            "port": device.port,
            "read_only": self.read_only or stop_only,
            "stop_only": stop_only,
            "actions": client.actions,
            "max_linear": self.max_linear,
            "max_angular": self.max_angular,
            "command_timeout": self.command_timeout,
            "rate": self.rate,
            "gamepad": {
                "linear_axis": self.gamepad.linear_axis,
                "angular_axis": self.gamepad.angular_axis,
                "enable_button": self.gamepad.enable_button,
                "scale_linear": self.gamepad.scale_linear,
                "scale_angular": self.gamepad.scale_angular,
                "deadzone": self.gamepad.deadzone,
                "stale_after": self.gamepad.stale_after,
            },
            "features": dict(self._profile.remote.features),
            "events": list(self._events),
            "path": [list(p) for p in self._path],
        }

    async def _send(self, client: _Client) -> None:
        """Send the newest state (a slow page gets fewer, never a backlog)."""
        ws = client.ws
        while True:
            await client.wake.wait()
            client.wake.clear()
            state, client.state = client.state, None
            if state is None:
                continue
            if client.events or client.notes:
                # The state is the same text for every page; its events are this page's.
                extra = {"events": list(client.events), "notes": list(client.notes)}
                client.events.clear()
                client.notes.clear()
                state = state[:-1] + ", " + json.dumps(extra)[1:]
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
                await self._handle(client, message.data.encode())
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
        client.notes.append({"refused": why, "total": self.refusals.total})
        if report is not None:
            _log.warning("web: refused %s", report.summary())

    async def _handle(self, client: _Client, raw: object) -> None:
        body = command_object(raw, limit=_MAX_MESSAGE)
        kind = body.get("type")
        if not isinstance(kind, str):
            raise CommandError("a message needs a string 'type'")
        if kind not in client.actions:
            if kind in ("drive", "release", "clear_faults", "led", "buzzer", "stop", "estop"):
                if client.stop_only:
                    mode = "stop only: the page limit is reached"
                elif self.read_only:
                    mode = "read-only"
                else:
                    mode = f"a {self.device.device_name}"
                raise CommandError(f"{kind!r} is not offered ({mode})")
            raise CommandError(f"unknown message type {kind[:40]!r}")
        if kind == "drive":
            _keys(body, ("linear", "angular", "t"))
            self._drive(client, body)
        elif kind == "stop":
            _keys(body, ())
            client.source.stop()
        elif kind == "estop":
            _keys(body, ())
            device: Any = self.device
            if not hasattr(device, "emergency_stop"):
                client.source.stop()
                client.notes.append({"done": f"stop (a {device.device_name} has no e-stop)"})
                return
            await device.emergency_stop()
            client.notes.append({"done": "estop"})
        else:
            self._request(client, kind, body)

    def _drive(self, client: _Client, body: dict[str, Any]) -> None:
        linear, angular = command_number(body, "linear"), command_number(body, "angular")
        for name, value, limit in (
            ("linear", linear, self.max_linear),
            ("angular", angular, self.max_angular),
        ):
            if abs(value) > limit * (1 + 1e-9):
                raise CommandError(f"{name} {value:g} is beyond the limit {limit:g}")
        age = 0.0
        if "t" in body:
            t = command_number(body, "t") / 1000.0
            if t < client.last_t:
                raise CommandError("t went back: messages out of order")
            client.last_t = t
            now = time.monotonic()
            client.offset = min(client.offset, now - t)
            age = now - t - client.offset  # later than the fastest delivery
            if age > self.command_timeout:
                raise CommandError(f"held up {age:.2f} s (longer than the deadman)")
        if self._closed:
            raise CommandError("the dashboard is closing")
        try:
            refusal = client.source.set_velocity(
                linear, angular, duration=self.command_timeout, age=age
            )
        except ChassisError as exc:  # not connected (an outage): this command is lost
            raise CommandError(f"not written: {exc}") from None
        if refusal is not None:
            raise CommandError(_refusal_text(refusal))
        self.commands += 1

    def _request(self, client: _Client, kind: str, body: Mapping[str, Any]) -> None:
        """Release, clear faults, LED, buzzer: in a task (a stop behind it never waits),
        one at a time per page."""
        device: Any = self.device
        if kind in ("led", "buzzer"):
            _keys(body, ("on",))
            on = body.get("on")
            if not isinstance(on, bool):
                raise CommandError(f"{kind} needs 'on': true or false")
            call = getattr(device, f"set_{kind}")
            args: tuple[Any, ...] = (on,)
        else:
            _keys(body, ())
            call = device.release_emergency_stop if kind == "release" else device.clear_faults
            args = ()
        if client.busy:
            raise CommandError(f"{kind}: the previous request is not answered yet")
        if self._tasks is None:
            raise CommandError("the dashboard is not running")
        client.busy = True

        async def run() -> None:
            try:
                with anyio.fail_after(_REQUEST_TIMEOUT):
                    await call(*args)
                client.notes.append({"done": kind})
            except (ChassisError, ValueError, TimeoutError) as exc:
                self._refuse(client, f"{kind} not done: {exc}")
            except Exception as exc:  # never the dashboard's end
                self.errors += 1
                _log.exception("web: %s failed", kind)
                self._refuse(client, f"{kind} not done: {type(exc).__name__}")
            finally:
                client.busy = False

        self._tasks.start_soon(run, name=f"web {kind}")

    # --- the device --------------------------------------------------------------------

    def _listen(self) -> Notifier:
        """Listen to the device's streams and events: each reading is kept as it
        arrives, inside the device's read path (no task per stream, nothing awaited);
        the state broadcast sends the newest."""
        notifier = Notifier(self.device)
        names = notifier.stream_names
        for stream in self._profile.remote.streams:
            if stream not in names:  # a profile naming a stream its device lacks
                self.errors += 1
                _log.error("web: %s has no %s stream to show", self.device.device_name, stream)
                continue
            keep = self._keep_odometry if stream == "odometry" else self._keeper(stream)
            notifier.listen(stream, self._guard(f"the {stream} stream", keep))
        notifier.listen("events", self._guard("the events", self._keep_event))
        return notifier

    def _guard(self, what: str, callback: Callable[[Any], None]) -> Callable[[Any], None]:
        """``callback``, never raising into the device's read path: an error is counted
        and logged (the first of each callback with its traceback)."""
        failed = 0

        def guarded(item: Any) -> None:
            nonlocal failed
            try:
                callback(item)
            except Exception:
                self.errors += 1
                failed += 1
                if failed == 1:
                    _log.exception("web: %s failed; the dashboard goes on", what)

        return guarded

    def _keeper(self, stream: str) -> Callable[[Any], None]:
        latest = self._latest

        def keep(reading: Any) -> None:
            latest[stream] = reading

        return keep

    def _keep_odometry(self, reading: Any) -> None:
        """Keep the newest odometry and the path (a point every `_PATH_STEP`)."""
        self._latest["odometry"] = reading
        x, y = float(reading.x), float(reading.y)
        path = self._path
        if not path or math.dist(path[-1], (x, y)) >= _PATH_STEP:
            path.append((round(x, 4), round(y, 4)))

    def _keep_event(self, event: Any) -> None:
        """Keep an event for the pages that open later and queue it for every open one."""
        body = outbound(event)
        body["time"] = body["timestamp"]  # wall time (the page's name for it)
        body["text"] = str(event)
        self._events.append(body)
        for client in self._clients:
            client.events.append(body)

    def _state(self) -> str:
        """The state every page is sent, as JSON text (a non-finite reading as ``null``:
        JSON has none)."""
        device = self.device
        latest = {name: outbound(reading) for name, reading in self._latest.items()}
        commanded = device.commanded_velocity
        estop = any("ESTOP" in block for block in device.motion.blocks)
        telemetry = self._latest.get("telemetry")
        if telemetry is not None and getattr(telemetry, "emergency_stopped", False):
            estop = True
        body = {
            "type": "state",
            "time": time.time(),
            "link": {"state": device.connection_state.name, "age": device.last_frame_age},
            "commanded": list(commanded) if commanded is not None else None,
            "written": list(device.written_velocity),
            "streams": latest,
            "odometry": latest.get("odometry"),
            "battery": self._charge(),
            "estop": estop,
            "refused": self.refusals.total,
            "commands": self.commands,
            "clients": len(self._clients),
        }
        try:
            return json.dumps(body, default=str, allow_nan=False)
        except ValueError:
            return json.dumps(_finite_only(body), default=str)

    def _charge(self) -> dict[str, Any] | None:
        """The state of charge (``battery=BatteryModel(...)``): ``{"percentage": 63.2 |
        None, "level": "OK" | "LOW" | "CRITICAL" | None}``, ``None`` while not known;
        ``None`` itself when the device has no model."""
        if self.device.battery_model is None:
            return None
        fields = battery_fields(self.device)
        return {"percentage": fields["battery_percentage"], "level": fields["battery_level"]}

    async def _broadcast(self) -> None:
        """Every ``1/rate`` s, the state (made once) to every page."""
        period = 1.0 / self.rate
        while True:
            await anyio.sleep(period)
            report = self.refusals.due()
            if report is not None:
                _log.warning("web: refused %s", report.summary())
            _log_door(self._door.due())
            if not self._clients:
                continue
            state = self._state()
            for client in self._clients:
                client.state = state
                client.wake.set()


def _log_door(report: RefusalReport | None) -> None:
    """Log what was refused at the door: the first at once, then a summary."""
    if report is None:
        return
    if report.count == 1:
        _log.warning("web: refused a request from %s: %s", report.where, report.why)
    else:
        _log.warning(
            "web: refused %d requests (%d since the start), latest from %s: %s",
            report.count,
            report.total,
            report.where,
            report.why,
        )


def _refusal_text(refusal: Refusal) -> str:
    """What a page is told of a velocity the motion core refused."""
    if refusal.reason == "blocked" and any("ESTOP" in b for b in refusal.blocks):
        return f"the emergency stop is engaged: release it first ({refusal.detail})"
    return refusal.detail


def _finite_only(value: Any) -> Any:
    """``value`` with every non-finite float as ``None``."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_only(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_only(v) for v in value]
    return value
