"""What a [`FoxgloveServer`][chassis_sdk.integrations.foxglove.FoxgloveServer] refused, and the
errors caught in its callbacks: counted, logged and shown to the app as a warning
status, rate-limited and summarised by `Refusals`
(at most one report per `REPORT_INTERVAL` of each kind, the ones in between
summarised; the front sends what is pending every so often, and on leaving).

Called from foxglove-sdk's threads, the front's and the event loop's: every count and
summary is taken under a lock of its own.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from ..inbound import RefusalReport, Refusals

__all__ = ["REPORT_INTERVAL", "STATUS_HANDSHAKE", "STATUS_REFUSALS", "Reports", "shown"]

_log = logging.getLogger("chassis_sdk.integrations.foxglove")

#: Refusals are reported at most this often (seconds), the ones in between summarised.
REPORT_INTERVAL = 1.0
#: The ids of the warning statuses, one per kind of report: a new summary replaces the
#: one the app shows instead of piling up.
STATUS_REFUSALS = "chassis-sdk-refusals"
STATUS_HANDSHAKE = "chassis-sdk-handshake"


def shown(text: object, limit: int = 80) -> str:
    """A client's text as it goes into a log line or a status: bounded, and without
    quotes when it is plain (``/cmd_vel``), else as a repr (no control characters)."""
    value = str(text)
    short = value if len(value) <= limit else value[:limit] + "..."
    return short if short.isprintable() and " " not in short else repr(short)


class Reports:
    """The server's counts of what it refused and what failed, and their reports.

    Args:
        sdk_server: Returns foxglove-sdk's server the statuses go to (``None`` when
            there is none: stopped, or not yet started).
    """

    def __init__(self, sdk_server: Callable[[], Any]) -> None:
        self._sdk_server = sdk_server
        self._lock = threading.Lock()
        #: Client messages refused (not a well-formed Twist, on a channel not taken,
        #: from a client that did not come through the front, or refused by the device).
        self.rejected = 0
        #: Errors caught in the server's callbacks (each also reported).
        self.errors = 0
        #: Connections refused at the handshake (a bad Origin, a missing or wrong token).
        self.refused_connections = 0
        # On stop, every interval is taken as passed, so the last refusals are logged.
        self._stopping = False
        self._refusals = Refusals(REPORT_INTERVAL, clock=self._clock)
        self._handshakes = Refusals(REPORT_INTERVAL, clock=self._clock)

    def restart(self) -> None:
        """Fresh reporters for a new run (the last stop took every interval as passed);
        the counts go on."""
        self._refusals = Refusals(REPORT_INTERVAL, clock=self._clock)
        self._handshakes = Refusals(REPORT_INTERVAL, clock=self._clock)

    def _clock(self) -> float:
        return math.inf if self._stopping else time.monotonic()

    def refuse(self, where: str, why: str) -> None:
        """Count a refused client message; report it when a report is due."""
        with self._lock:
            self.rejected += 1
            report = self._refusals.add(where, why)
        if report is not None:
            self._send(report)

    def failed(self, where: str, exc: BaseException) -> None:
        """Count (and log) an error caught in a callback; report it when due."""
        _log.error("%s failed", where, exc_info=exc)
        with self._lock:
            self.errors += 1
            report = self._refusals.add(where, f"internal error: {type(exc).__name__}: {exc}")
        if report is not None:
            self._send(report)

    def refused_handshake(self, peer: str, why: str) -> None:
        """Count a connection refused at the handshake; report it when due."""
        with self._lock:
            self.refused_connections += 1
            report = self._handshakes.add(peer, why)
        if report is not None:
            self._send_handshake(report)

    def flush(self) -> None:
        """Send what is pending (called every so often by the front)."""
        with self._lock:
            report = self._refusals.due()
            handshakes = self._handshakes.due()
        if report is not None:
            self._send(report)
        if handshakes is not None:
            self._send_handshake(handshakes)

    def flush_final(self) -> None:
        """Send everything pending now, every interval taken as passed (on leaving)."""
        self._stopping = True  # what is pending is reported now, not lost
        try:
            self.flush()
        finally:
            self._stopping = False

    def _send(self, report: RefusalReport) -> None:
        line = report.summary()
        if report.count > 1:
            line += f" ({report.total} in all)"
        _log.warning("%s", line)
        self._status(line, STATUS_REFUSALS)

    def _send_handshake(self, report: RefusalReport) -> None:
        if report.count == 1:
            line = f"refused a connection from {report.where}: {report.why}"
        else:
            line = (
                f"refused {report.count} connections ({report.total} in all), "
                f"the latest from {report.where}: {report.why}"
            )
        _log.warning("%s", line)
        self._status(line, STATUS_HANDSHAKE)

    def _status(self, message: str, kind: str) -> None:
        server = self._sdk_server()
        if server is not None:
            from foxglove.websocket import StatusLevel

            with contextlib.suppress(Exception):  # the server is stopping
                server.publish_status(message[:1000], StatusLevel.Warning, id=kind)
