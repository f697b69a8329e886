"""Access and HTTP: who may connect, the aiohttp application and its routes, the static
page, and the account of what was refused at the door.

Loopback by default: then only requests whose ``Host`` names this computer are served.
With a token, every request but the static files must carry it (the cookie for this
port, ``?token=`` or ``Authorization: Bearer``), compared in constant time; the page's
address with ``?token=`` swaps it for the cookie. A WebSocket handshake's ``Origin``
must be the page's own or one allowed. A refused request is counted and logged: the
first at once, then at most one summary a second. aiohttp is given (``web``), not
imported: the package imports without it.
"""

from __future__ import annotations

import hmac
import logging
from collections.abc import Awaitable, Callable, Iterable
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from ...errors import ChassisError
from ..access import given_tokens, is_loopback, origin_key
from ..inbound import RefusalReport, Refusals
from .page import MAX_MESSAGE

__all__ = ["Access"]

_log = logging.getLogger("chassis_sdk.integrations.web")

#: Seconds an idle HTTP connection is kept open.
_KEEPALIVE = 10.0
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


class Access:
    """The door: the checks every request passes, the page and its static files.

    Args:
        web: ``aiohttp.web``.
        host: The address served (loopback: only a ``Host`` naming this computer).
        token: The token required, or ``None``.
        origins: WebSocket ``Origin`` values let in besides the page's own.
        port: The port served (`port` is set again once bound).
    """

    def __init__(
        self, web: Any, host: str, token: str | None, origins: Iterable[str], port: int
    ) -> None:
        self._web = web
        self._host = host
        self._token = token
        self._origins = frozenset(origins)
        self.port = port
        #: Requests and handshakes refused.
        self.refused = 0
        self._door = Refusals()

    def _cookie(self) -> str:
        return f"chassis_sdk_token_{self.port}"

    def check(self, request: Any) -> Any:
        """The HTTP error for a request that may not be served, else ``None``."""
        web = self._web
        # The header itself: aiohttp's request.host falls back to a blocking
        # socket.getfqdn() in some versions when there is none.
        host_header = request.headers.get("Host")
        if not host_header:
            self.refuse(request, "no Host header")
            return web.Response(status=400, text="no Host header\n")
        if is_loopback(self._host):
            try:
                host = urlsplit(f"//{host_header}").hostname or ""
            except ValueError:
                host = ""
            if not is_loopback(host):
                self.refuse(request, f"Host {host_header[:100]!r} is not this computer")
                return web.Response(status=403, text="Host is not this computer\n")
        if self._token is None:
            return None
        given = given_tokens(request.path_qs, request.headers.getall("Authorization", []))
        cookie = request.cookies.get(self._cookie())
        if cookie is not None:
            given.append(cookie)
        if not any(hmac.compare_digest(g.encode(), self._token.encode()) for g in given):
            self.refuse(request, "no token" if not given else "a wrong token")
            return web.Response(
                status=401,
                text="open the address chassis-sdk web printed (it carries ?token=...)\n",
            )
        return None

    def check_socket(self, request: Any) -> Any:
        """`check`, and the handshake's ``Origin``: the HTTP error, else ``None``."""
        refused = self.check(request)
        if refused is not None:
            return refused
        why = self._origin_refused(request)
        if why is None:
            return None
        self.refuse(request, why)
        return self._web.Response(status=403, text=f"{why}\n")

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

    def refuse(self, request: Any, why: str) -> None:
        """Count a refused request; log the first at once, then a summary a second."""
        self.refused += 1
        _log_door(self._door.add(request.remote or "?", why))

    def log_due(self) -> None:
        """Log the summary of refused requests, if one is due."""
        _log_door(self._door.due())

    async def _secure(self, request: Any, response: Any) -> None:
        for name, value in _SECURITY_HEADERS.items():
            response.headers.setdefault(name, value)

    async def _index(self, request: Any) -> Any:
        web = self._web
        refused = self.check(request)
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

    async def serve(self, socket: Callable[[Any], Awaitable[Any]]) -> Any:
        """Bind and serve the page, its static files and ``socket`` at ``/ws``; the
        runner (`port` is set to the port bound).

        Raises:
            ChassisError: The address cannot be bound (in use, not this computer's).
        """
        web = self._web
        # An idle connection is closed after _KEEPALIVE (aiohttp's default is an hour:
        # anyone who reaches the port could hold descriptors the device needs).
        app = web.Application(
            client_max_size=MAX_MESSAGE,
            handler_args={"max_field_size": 8190, "keepalive_timeout": _KEEPALIVE},
        )
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", socket)
        app.router.add_get("/static/{name}", self._static)
        app.on_response_prepare.append(self._secure)
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)
        await runner.setup()
        site = web.TCPSite(runner, self._host, self.port, reuse_address=True)
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise ChassisError(
                f"cannot serve on {self._host}:{self.port}: {exc.strerror or exc}"
            ) from None
        if runner.addresses:
            self.port = runner.addresses[0][1]
        return runner


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
