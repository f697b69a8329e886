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

The package: ``page.py`` is the per-page protocol (sans-IO: a message to an action, the
hello and notes a page gets); ``state.py`` the state pages see; ``http.py`` who may
connect and the HTTP side; ``sockets.py`` the WebSocket of each page; this module the
dashboard itself: its options, its lifetime, and the wiring of the rest.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable, Iterable
from types import TracebackType
from typing import Any, Self

import anyio

from ...core.device import Device
from ...core.validation import check_int, check_real
from ...devices import profile
from ...errors import ChassisError, install_hint
from ..access import check_allowed_origin, check_token, made_token
from .http import Access
from .page import (
    DEFAULT_MAX_ANGULAR,
    DEFAULT_MAX_LINEAR,
    MAX_DEADZONE,
    GamepadMapping,
    Terms,
    limit,
    offered,
)
from .sockets import MAX_CLIENTS, STOP_ONLY_PAGES, PageSockets
from .state import StateModel

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
            raise ImportError(f"the web dashboard needs aiohttp: {install_hint('web')}") from None
        if not isinstance(host, str) or not host:
            raise ValueError(f"host must be an address, got {host!r}")
        check_int(port, "port", low=0, high=65535)
        if isinstance(allow_origins, str):
            raise ValueError("allow_origins is a list of origins, not one string")
        origins = frozenset(check_allowed_origin(o) for o in allow_origins)
        if token is not None:
            check_token(token)
        self._token, _ = made_token(host, token)
        timeout = command_timeout if command_timeout is not None else device.command_timeout
        timeout = 0.5 if timeout is None else timeout
        timeout = check_real(timeout, "command_timeout", low=0, low_open=True, unit="s")
        check_real(rate, "rate", low=1, high=50, unit="updates a second")
        check_int(max_clients, "max_clients", low=1)
        limits = device.limits
        self.max_linear = limit("max_linear", max_linear, limits.max_linear, DEFAULT_MAX_LINEAR)
        self.max_angular = limit(
            "max_angular", max_angular, limits.max_angular, DEFAULT_MAX_ANGULAR
        )
        self.device = device
        self.host = host
        self.read_only = bool(read_only)
        self.command_timeout = timeout
        self.rate = float(rate)
        self.gamepad = gamepad if gamepad is not None else GamepadMapping()
        self.max_clients = max_clients
        remote = profile(device.device_name).remote
        features = remote.features
        terms = Terms(
            device_name=device.device_name,
            read_only=self.read_only,
            actions=offered(device, self.read_only, features),
            max_linear=self.max_linear,
            max_angular=self.max_angular,
            command_timeout=timeout,
            rate=self.rate,
            gamepad=self.gamepad,
            features=features,
            estop=hasattr(device, "emergency_stop"),
        )
        #: Errors caught in the dashboard's own tasks and callbacks (logged with their
        #: traceback: each of a task, the first of each callback).
        self.errors = 0
        self._access = Access(web, host, token, origins, port)
        self._model = StateModel(device, remote.streams, self._count_error)
        self._pages = PageSockets(
            web, device, terms, self._access, self._model, max_clients, self._count_error
        )
        #: Messages refused (counted by source and reason).
        self.refusals = self._pages.refusals
        self._runner: Any = None
        self._background: asyncio.Task[None] | None = None

    def _count_error(self) -> None:
        self.errors += 1

    # --- what it is --------------------------------------------------------------------

    @property
    def commands(self) -> int:
        """Velocity commands taken by the motion core."""
        return self._pages.commands

    @property
    def refused(self) -> int:
        """Messages refused since the start."""
        return self.refusals.total

    @property
    def refused_connections(self) -> int:
        """Requests and handshakes refused at the door."""
        return self._access.refused

    @property
    def clients(self) -> int:
        """Pages connected now."""
        return len(self._pages.clients)

    @property
    def token(self) -> str | None:
        """The token required (the one made, beyond loopback), or ``None``."""
        return self._token

    @property
    def port(self) -> int:
        """The TCP port served (the one picked, for 0)."""
        return self._access.port

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
        self._runner = await self._access.serve(self._pages.socket)
        if self.read_only:
            # Nothing written at close that no page asked for (a page's STOP is written,
            # and then the close's zero too).
            self.device.motion.zero_on_close = False
        self._model.listen()
        # The dashboard's own tasks live in a task of their own, not in the caller's:
        # nothing of theirs can cancel the application around the dashboard.
        self._background = asyncio.get_running_loop().create_task(
            self._run_tasks(), name="web dashboard"
        )

    async def _run_tasks(self) -> None:
        async with anyio.create_task_group() as tg:
            self._pages.tasks = tg  # where the requests run
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

    async def _broadcast(self) -> None:
        """Every ``1/rate`` s, the state (made once) to every page; and the summaries of
        what was refused, when due."""
        period = 1.0 / self.rate
        pages = self._pages
        while True:
            await anyio.sleep(period)
            pages.log_refusals()
            self._access.log_due()
            if pages.clients:
                pages.send_all(self._model.snapshot(refused=self.refused, commands=self.commands))

    async def aclose(self) -> None:
        """Stop the robot if a page was driving it, close every page, stop serving.

        From its first line no drive message is taken and none is written: the pages
        still open while they are closed cannot move the robot after its zero.
        """
        if self._pages.closed:
            return
        driving = self._pages.closing()
        self._model.close()  # no more readings kept
        background = self._background
        if background is not None:
            background.cancel()  # the broadcast, the requests
        for source in driving:
            with contextlib.suppress(ChassisError):
                source.stop()
        with anyio.CancelScope(shield=True):
            await self._pages.close_all()
            if self._runner is not None:
                with anyio.move_on_after(2.0):
                    await self._runner.cleanup()
            if background is not None:
                await asyncio.wait([background])  # (its cancellation is not ours)
