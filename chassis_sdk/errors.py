"""Exceptions raised by chassis_sdk.

Errors are split by whose fault they are, as h11 does:

* the caller's fault: a bad argument raises the built-in :class:`ValueError` before a
  single byte is written, so nothing is half done;
* the link's or the device's fault: a subclass of :class:`ChassisError`.

:class:`asyncio.CancelledError` is never wrapped in any of these.
"""

from __future__ import annotations

__all__ = [
    "ChassisError",
    "ConnectionLostError",
    "NotConnectedError",
    "PortOpenError",
    "ProtocolError",
    "RequestTimeoutError",
]


class ChassisError(Exception):
    """Base class of every error chassis_sdk raises on its own account."""


class RequestTimeoutError(ChassisError, TimeoutError):
    """A request got no reply within ``request_timeout`` on any of its attempts."""


class ConnectionLostError(ChassisError, ConnectionError):
    """The port went away (unplugged, closed by the peer, I/O error) while in use."""


class NotConnectedError(ChassisError):
    """The device is not connected: never opened, closed, or reconnecting."""


class PortOpenError(ChassisError, ConnectionError):
    """The port could not be opened (missing device, permission denied, refused)."""


class ProtocolError(ChassisError):
    """The device sent something well framed that makes no sense (for example, month 13)."""
