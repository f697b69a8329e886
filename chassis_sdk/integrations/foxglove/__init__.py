"""The live Foxglove server (``pip install -e ".[foxglove]"``).

* `server`: `FoxgloveServer`: channels, Teleop clients as motion-core sources, services;
* `front`: the WebSocket front: Origin, Host and token checks before foxglove-sdk;
* `reports`: refusals and failures as rate-limited status messages.
"""

from __future__ import annotations

from .server import (
    APP_ORIGINS,
    MAX_CLIENT_CHANNELS,
    SAFE_SERVICES,
    SERVICES,
    TWIST_SCHEMAS,
    FoxgloveServer,
    check_access,
    is_loopback,
)

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
