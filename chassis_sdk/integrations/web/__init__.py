"""The web dashboard (``pip install 'chassis-sdk[web]'``).

* `server`: `WebDashboard`: HTTP, the WebSocket per page (each page a motion-core
  source), the state pages see;
* ``static/``: the page (HTML, JavaScript, CSS).
"""

from __future__ import annotations

from .server import (
    DEFAULT_MAX_ANGULAR,
    DEFAULT_MAX_LINEAR,
    MAX_CLIENTS,
    MAX_DEADZONE,
    STOP_ONLY_PAGES,
    GamepadMapping,
    WebDashboard,
)

__all__ = [
    "DEFAULT_MAX_ANGULAR",
    "DEFAULT_MAX_LINEAR",
    "MAX_CLIENTS",
    "MAX_DEADZONE",
    "STOP_ONLY_PAGES",
    "GamepadMapping",
    "WebDashboard",
]
