"""Exceptions raised by chassis_sdk.

Errors are split by whose fault they are, as h11 does:

* the caller's fault: a bad argument raises a built-in error before a single byte is
  written, so nothing is half done: `TypeError` for a wrong type (a ``str`` or
  ``None`` where a number is wanted), `ValueError` for a bad value of the right
  type (NaN, out of range), as the standard library does;
* the link's or the device's fault: a subclass of [`ChassisError`][chassis_sdk.ChassisError].

`asyncio.CancelledError` is never wrapped in any of these.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "ChassisError",
    "ConnectionLostError",
    "MotionBlockedError",
    "MovePreemptedError",
    "MoveTimeoutError",
    "NotConnectedError",
    "PortOpenError",
    "ProtocolError",
    "RequestTimeoutError",
    "install_hint",
]


def install_hint(extra: str) -> str:
    """The command that installs ``extra`` from the checkout: ``pip install -e ".[web]"``.

    The one form of every hint the SDK prints for a missing extra (the command line's,
    the library's): chassis-sdk is not on a package index, so ``chassis-sdk[web]``
    cannot be installed by name; this runs in the repository's directory.
    """
    return f'pip install -e ".[{extra}]"'


class ChassisError(Exception):
    """Base class of every error chassis_sdk raises on its own account."""


class RequestTimeoutError(ChassisError, TimeoutError):
    """A request got no reply within ``request_timeout`` on any of its attempts, or a
    wait (``wait_for``, ``wait_connected``) ended at its timeout: every timeout the SDK
    raises, a [`ChassisError`][chassis_sdk.ChassisError] and a `TimeoutError` both."""


class ConnectionLostError(ChassisError, ConnectionError):
    """The port went away (unplugged, closed by the peer, I/O error) while in use."""


class NotConnectedError(ChassisError):
    """The device is not connected: never opened, closed, or reconnecting."""


class MotionBlockedError(ChassisError):
    """A velocity was refused and nothing was written: an e-stop (of any origin), a
    latched bumper, a driver fault or a lost link blocks motion, or another source
    drives under a lease of higher priority.

    Attributes:
        reasons: What refused it: the blocks by their flag names (``("HARDWARE_ESTOP",)``,
            ``("SOFTWARE_ESTOP", "FRONT_BUMPER")``, ``("LINK_LOST",)``), or
            ``("DRIVEN",)`` when another source holds the lease (the message names it).
    """

    def __init__(self, message: str, reasons: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.reasons = reasons


class MoveTimeoutError(ChassisError, TimeoutError):
    """A goal (``drive_distance``, ``rotate``, ``go_to``) did not finish in its
    ``timeout``; the robot was stopped.

    Attributes:
        result: Where it got (a [`MoveResult`][chassis_sdk.MoveResult], ``ended="timeout"``).
    """

    def __init__(self, message: str, result: Any) -> None:
        super().__init__(message)
        #: A `MoveResult` (typed ``Any`` here: the errors import nothing of the runtime).
        self.result = result


class MovePreemptedError(ChassisError):
    """A goal was ended by another source: one of higher priority took over, a stop
    came from elsewhere, or a newer goal began. It leaves the robot to whoever took
    over.

    Attributes:
        result: Where it got (a [`MoveResult`][chassis_sdk.MoveResult], ``ended="preempted"``).
    """

    def __init__(self, message: str, result: Any) -> None:
        super().__init__(message)
        #: A `MoveResult` (typed ``Any`` here: the errors import nothing of the runtime).
        self.result = result


class PortOpenError(ChassisError, ConnectionError):
    """The port could not be opened (missing device, permission denied, refused)."""


class ProtocolError(ChassisError):
    """The device sent something well framed that makes no sense (for example, month 13)."""
