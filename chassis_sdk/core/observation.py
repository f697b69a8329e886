"""What a device reports beyond its own messages: its events, the pose dead-reckoned
from its velocities, and its battery watch."""

from __future__ import annotations

import logging

from .diagnosis import Findings
from .dispatch import Broadcast
from .events import BatteryMonitor, RobotEvent
from .odometry import Odometry, OdometryIntegrator
from .supervisor import ConnectionState
from .transport import backend_name

__all__ = ["Reports"]


class Reports:
    """A device's events, odometry and battery watch (one per device).

    Args:
        port: For the log.
        log: Where events are logged.
        events: The device's ``events`` stream.
        odometry: The device's ``odometry`` stream.
        battery_low: Voltage below which ``BATTERY_LOW`` is reported, or ``None``.
    """

    def __init__(
        self,
        port: str,
        log: logging.Logger,
        events: Broadcast[RobotEvent],
        odometry: Broadcast[Odometry],
        battery_low: float | None,
    ) -> None:
        self._port = port
        self._log = log
        self.events = events
        self.odometry = odometry
        self.pose = OdometryIntegrator()
        self.battery_monitor = BatteryMonitor(battery_low)

    def emit(self, event: RobotEvent) -> None:
        """Log ``event`` and publish it on ``events``."""
        self._log.info("%s: %s", self._port, event)
        self.events.publish(event)

    def battery(self, voltage: float, timestamp: float) -> None:
        """A battery reading: an event if it crosses the threshold."""
        event = self.battery_monitor.update(voltage, timestamp)
        if event is not None:
            self.emit(event)

    def integrate(
        self, linear: float, angular: float, timestamp: float, heading: float | None
    ) -> None:
        """One velocity sample into the pose (published only if anyone listens)."""
        stream = self.odometry
        if stream.listened:
            stream.publish(self.pose.update(linear, angular, timestamp, heading))
        else:  # nobody listens: the pose is built when asked (latest_odometry)
            self.pose.advance(linear, angular, timestamp, heading)
            stream.latest = None

    @property
    def latest_odometry(self) -> Odometry | None:
        stream = self.odometry
        if stream.latest is None:
            stream.latest = self.pose.current()
        return stream.latest

    def reset_pose(self, x: float, y: float, heading: float) -> None:
        _ = self.latest_odometry  # the last pose before the reset stays the latest
        self.pose.reset(x, y, heading)

    def findings(self, state: ConnectionState, last_frame_age: float | None) -> Findings:
        """The link's and the battery's findings, for ``diagnose()`` to add to."""
        found = Findings()
        if state is not ConnectionState.CONNECTED:
            found.fault(f"link {state.value}")
        if last_frame_age is None:
            found.fault("no valid frame received yet")
        else:
            found.note(f"last frame {last_frame_age:.2f} s ago, via {backend_name()}")
        if self.battery_monitor.low:
            found.fault(f"battery below {self.battery_monitor.threshold:g} V")
        return found
