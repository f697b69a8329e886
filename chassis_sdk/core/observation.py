"""The observation facet of a device: its events, diagnosis findings, odometry and
counters."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, ClassVar, TypeVar

import anyio

from ..errors import NotConnectedError, ProtocolError, RequestTimeoutError
from .diagnosis import Diagnosis, Findings
from .dispatch import Broadcast, Streams, Subscription
from .events import BatteryMonitor, RobotEvent
from .framing import FrameDecoder
from .odometry import Odometry, OdometryIntegrator
from .requests import Requester
from .stats import LinkStats
from .supervisor import ConnectionState, LinkSupervisor
from .transport import backend_name
from .validation import check_real
from .watchdog import VelocityWatchdog

__all__ = ["Observation"]

T = TypeVar("T")
D = TypeVar("D", bound=Diagnosis)


class Observation:
    """``events()``, ``odometry()``, ``stats`` and the link's and battery's findings.

    A device with its own heading source overrides :meth:`_on_odometry_reset`, and one
    whose frames are numbered, :meth:`_sequence_gaps`.
    """

    port: str
    kind: ClassVar[str]
    _log: logging.Logger
    _decoder: FrameDecoder[Any]
    _link: LinkSupervisor[Any]
    _requests: Requester[Any]
    _streams: Streams
    _watchdog: VelocityWatchdog
    _events: Broadcast[RobotEvent]
    _odometry: Broadcast[Odometry]
    _pose: OdometryIntegrator
    _battery_monitor: BatteryMonitor

    def _subscribe(self, stream: Broadcast[Any]) -> Subscription[Any]:
        raise NotImplementedError  # Device's

    async def _first_match(
        self, stream: Broadcast[T], predicate: Callable[[T], bool], timeout: float, what: str
    ) -> T:
        """The latest message of ``stream`` if it satisfies ``predicate``, else the next
        one that does (a device's ``wait_for``).

        Raises:
            TimeoutError: None did within ``timeout`` seconds.
            ValueError: ``timeout`` is not a finite number > 0.
            NotConnectedError: The device was closed meanwhile.
        """
        timeout = check_real(timeout, "timeout", low=0, low_open=True, unit="s")
        subscription: Subscription[T] = self._subscribe(stream)
        async with subscription as items:
            latest = stream.latest
            if latest is not None and predicate(latest):
                return latest
            with anyio.move_on_after(timeout):
                async for item in items:
                    if predicate(item):
                        return item
                raise NotConnectedError(f"{self.port} was closed while waiting")
        raise TimeoutError(f"{self.port}: no {what} satisfied the condition in {timeout:g} s")

    async def verify(self, timeout: float = 3.0) -> None:
        """Make sure the device on the port is this one: wait until a valid frame of
        its protocol arrives (returns at once if one has). Call it before driving a
        robot whose port you are not sure of: another device, a wrong baud rate and a
        silent port each give one clear error instead of a robot that does not move.

        Raises:
            ProtocolError: Bytes arrive but none forms a frame of this protocol.
            RequestTimeoutError: Nothing arrived within ``timeout`` seconds.
            NotConnectedError: The port is not open.
            ValueError: ``timeout`` is not a finite number > 0.
        """
        timeout = check_real(timeout, "timeout", low=0, low_open=True, unit="s")
        end = time.monotonic() + timeout
        while not self._decoder.stats.frames:
            if not self._link.is_open:
                raise NotConnectedError(f"{self.port} is {self._link.state.value}")
            if time.monotonic() >= end:
                received = self._decoder.stats.bytes_received
                if received:
                    raise ProtocolError(
                        f"{received} bytes arrived on {self.port} but none is a {self.kind} "
                        "frame: is it another device, or the wrong baud rate?"
                    )
                raise RequestTimeoutError(
                    f"nothing arrived from {self.port} within {timeout:g} s (is the device "
                    "on, and is this its port?)"
                )
            await anyio.sleep(0.02)

    def _on_odometry_reset(self, heading: float) -> None:
        """A device with its own heading source resets it too."""

    def _sequence_gaps(self) -> int:
        """Breaks in the device's frame numbers (protocols that number frames)."""
        return 0

    def _emit(self, event: RobotEvent) -> None:
        self._log.info("%s: %s", self.port, event)
        self._events.publish(event)

    def _battery(self, voltage: float, timestamp: float) -> None:
        event = self._battery_monitor.update(voltage, timestamp)
        if event is not None:
            self._emit(event)

    def events(self) -> Subscription[RobotEvent]:
        """Subscribe to :class:`~chassis_sdk.RobotEvent` edges: e-stops, bumpers, driver
        faults, docking changes (chassis), battery low/ok (with ``battery_low``), and
        the link going stale, lost and restored. Each edge is reported once.
        """
        return self._subscribe(self._events)

    @property
    def battery_low(self) -> float | None:
        """Voltage below which ``BATTERY_LOW`` is reported (``None``: not watched)."""
        return self._battery_monitor.threshold

    def _report(self, found: Findings, cls: type[D], **read: Any) -> D:
        """A :class:`Diagnosis` (``cls``: it or a device's subclass, with what was
        ``read`` for it) of these findings, now."""
        return cls(
            self.kind,
            self.port,
            self._link.state,
            self.stats,
            tuple(found.faults),
            tuple(found.notes),
            **read,
        )

    def _findings(self) -> Findings:
        """The link's and the battery's findings, for ``diagnose()`` to add to."""
        found = Findings()
        if self._link.state is not ConnectionState.CONNECTED:
            found.fault(f"link {self._link.state.value}")
        age = self.last_frame_age
        if age is None:
            found.fault("no valid frame received yet")
        else:
            found.note(f"last frame {age:.2f} s ago, via {backend_name()}")
        if self._battery_monitor.low:
            found.fault(f"battery below {self._battery_monitor.threshold:g} V")
        return found

    # --- odometry ---------------------------------------------------------------------------

    def _integrate(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> None:
        stream = self._odometry
        if stream.listened:
            stream.publish(self._pose.update(linear, angular, timestamp, heading))
        else:  # nobody listens: the pose is built when asked (latest_odometry)
            self._pose.advance(linear, angular, timestamp, heading)
            stream.latest = None

    def odometry(self) -> Subscription[Odometry]:
        """Subscribe to the pose dead-reckoned from the device's reported velocities:
        an async iterator of :class:`~chassis_sdk.Odometry`, one per velocity sample.

        Integration runs all the time, subscribed or not, using the samples'
        timestamps, so irregular intervals and dropped frames do not bias it; a gap
        longer than half a second (an outage) is not integrated. See
        ``configure_odometry`` for the sources.
        """
        return self._subscribe(self._odometry)

    @property
    def latest_odometry(self) -> Odometry | None:
        """The most recent :class:`~chassis_sdk.Odometry`, or ``None``."""
        stream = self._odometry
        if stream.latest is None:
            stream.latest = self._pose.current()
        return stream.latest

    def reset_odometry(self, x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> None:
        """Set the current pose (default: the origin, heading 0) and integrate from it.

        Raises:
            ValueError: A value is not finite.
        """
        heading = check_real(heading, "heading")
        x, y = check_real(x, "x"), check_real(y, "y")
        _ = self.latest_odometry  # the last pose before the reset stays the latest
        self._pose.reset(x, y, heading)
        self._on_odometry_reset(heading)

    # --- observability ------------------------------------------------------------------------

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link counters (see :class:`LinkStats`)."""
        d = self._decoder.stats
        link, requests = self._link, self._requests
        return LinkStats(
            bytes_received=d.bytes_received,
            bytes_sent=link.writer.bytes_sent,
            frames=d.frames,
            frames_sent=link.writer.frames_sent,
            bytes_dropped=d.bytes_dropped,
            checksum_errors=d.checksum_errors,
            malformed_frames=d.malformed_frames,
            length_mismatches=d.length_mismatches,
            misaligned_frames=d.misaligned_frames,
            unmatched_replies=requests.unmatched,
            late_replies=requests.late,
            frames_discarded=link.discarded,
            queue_drops=self._streams.dropped,
            sequence_gaps=self._sequence_gaps(),
            reconnects=link.reconnects,
            resends=self._watchdog.resends,
            command_expiries=self._watchdog.expiries,
        )

    @property
    def last_frame_age(self) -> float | None:
        """Seconds since the last valid frame of any kind arrived (across reconnects),
        or ``None`` if none has."""
        last = self._link.last_frame_time
        return None if last is None else time.monotonic() - last
