"""The web dashboard (the ``web`` extra: ``pip install -e ".[web]"``).

* `server`: `WebDashboard`: the options, the lifetime, the wiring of the rest;
* `page`: the per-page protocol, sans-IO: a page's message to an action (drive, stop,
  e-stop, a request), the page clock, the limits; the hello and notes a page gets;
  `GamepadMapping`;
* `state`: the state pages see (the newest readings, the path, the events);
* `http`: who may connect (Host, token, Origin), the aiohttp application, the static
  files, the account of refused requests;
* `sockets`: the WebSocket of each page (each page a motion-core source);
* ``static/``: the page (HTML, JavaScript, CSS).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .page import DEFAULT_MAX_ANGULAR, DEFAULT_MAX_LINEAR, MAX_DEADZONE, GamepadMapping
    from .server import WebDashboard
    from .sockets import MAX_CLIENTS, STOP_ONLY_PAGES

# Imported on first use: the per-page protocol (``page``) loads without the runtime.
_LAZY = {
    "DEFAULT_MAX_ANGULAR": ".page",
    "DEFAULT_MAX_LINEAR": ".page",
    "MAX_DEADZONE": ".page",
    "GamepadMapping": ".page",
    "WebDashboard": ".server",
    "MAX_CLIENTS": ".sockets",
    "STOP_ONLY_PAGES": ".sockets",
}

__all__ = [
    "DEFAULT_MAX_ANGULAR",
    "DEFAULT_MAX_LINEAR",
    "MAX_CLIENTS",
    "MAX_DEADZONE",
    "STOP_ONLY_PAGES",
    "GamepadMapping",
    "WebDashboard",
]

__getattr__, __dir__ = _lazy(__name__, _LAZY, globals())
