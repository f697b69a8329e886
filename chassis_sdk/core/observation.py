"""What a device reports beyond its own messages: its events, the pose dead-reckoned
from its velocities, its battery watch and its state of charge."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from .battery import BatteryLevel, BatteryModel
from .calibration import Calibration
from .diagnosis import Findings
from .dispatch import Broadcast
from .events import BatteryMonitor, EventKind, RobotEvent
from .odometry import Odometry, OdometryIntegrator
from .supervisor import ConnectionState
from .transport import backend_name

if TYPE_CHECKING:
    from .motion.reflexes import ReflexRunner

__all__ = ["Reports"]

#: The battery model's levels the reflexes are told of.
_LEVELS = (EventKind.BATTERY_CRITICAL, EventKind.BATTERY_OK)


class Reports:
    """A device's events, odometry and battery watch (one per device).

    Args:
        port: For the log.
        log: Where events are logged.
        events: The device's ``events`` stream.
        odometry: The device's ``odometry`` stream.
        battery_low: Voltage below which ``BATTERY_LOW`` is reported, or ``None``.
        battery: The state-of-charge estimator, or ``None``.
    """

    def __init__(
        self,
        port: str,
        log: logging.Logger,
        events: Broadcast[RobotEvent],
        odometry: Broadcast[Odometry],
        battery_low: float | None,
        battery: BatteryModel | None = None,
    ) -> None:
        self._port = port
        self._log = log
        self.events = events
        self.odometry = odometry
        self.pose = OdometryIntegrator()
        self.battery_monitor = BatteryMonitor(battery_low)
        self.battery_model = battery
        #: The device's calibration, applied to every velocity sample (`integrate`).
        self.calibration = Calibration()
        #: The device's reflexes, told of every velocity sample, battery reading and
        #: battery level (``None``: none).
        self.reflexes: ReflexRunner | None = None

    @property
    def watches_voltage(self) -> bool:
        """Whether battery readings are wanted (``battery_low``, or a reflex's)."""
        r = self.reflexes
        return self.battery_monitor.threshold is not None or (r is not None and r.watches_voltage)

    def emit(self, event: RobotEvent) -> None:
        """Log ``event`` and publish it on ``events`` (a battery level also to the
        reflexes)."""
        self._log.info("%s: %s", self._port, event)
        self.events.publish(event)
        r = self.reflexes
        if r is not None and event.kind in _LEVELS and event.voltage is not None:
            r.battery_level(
                event.kind is EventKind.BATTERY_CRITICAL, event.voltage, event.timestamp
            )

    def battery(self, voltage: float, timestamp: float) -> None:
        """A battery reading: an event if it crosses the threshold."""
        monitor = self.battery_monitor
        if monitor.threshold is not None:  # (no call per frame when nothing is watched)
            event = monitor.update(voltage, timestamp)
            if event is not None:
                self.emit(event)
        r = self.reflexes
        if r is not None and r.watches_voltage:
            r.voltage(voltage, timestamp)

    def charge(
        self, voltage: float, current: float | None, timestamp: float, loaded: bool = False
    ) -> None:
        """A reading for the state of charge: ``BATTERY_LOW``, ``BATTERY_CRITICAL`` or
        ``BATTERY_OK`` when its level changes (each once per crossing; a first estimate
        already low reports ``BATTERY_LOW``, and ``BATTERY_CRITICAL`` if it is)."""
        model = self.battery_model
        if model is None:
            return
        before = model.level
        percentage = model.update(voltage, current, now=timestamp, loaded=loaded)
        after = model.level
        if after is None or after is before:
            return
        old = BatteryLevel.OK if before is None else before
        kinds = []
        if after is BatteryLevel.OK:
            if before is not None:  # a first estimate that is OK is no edge
                kinds.append(EventKind.BATTERY_OK)
        else:
            if old is BatteryLevel.OK:
                kinds.append(EventKind.BATTERY_LOW)
            if after is BatteryLevel.CRITICAL:
                kinds.append(EventKind.BATTERY_CRITICAL)
        for kind in kinds:
            self.emit(RobotEvent(kind, "", timestamp, voltage=voltage, percentage=percentage))

    @property
    def battery_percentage(self) -> float | None:
        """The estimated state of charge, or ``None`` (no model, or not yet known)."""
        model = self.battery_model
        return None if model is None else model.percentage

    def integrate(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> None:
        """One velocity sample into the pose, scaled by the calibration (published only
        if anyone listens)."""
        cal = self.calibration
        linear, angular = linear * cal.linear_scale, angular * cal.angular_scale
        stream = self.odometry
        if stream.listened:
            stream.publish(self.pose.update(linear, angular, timestamp, heading))
        else:  # nobody listens: integrated and built when asked (latest_odometry)
            self.pose.defer(linear, angular, timestamp, heading)
            stream.latest = None
        r = self.reflexes
        if r is not None:
            r.moved(linear, timestamp)

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
        model = self.battery_model
        if model is not None:
            if model.percentage is None:
                found.note("battery charge not yet known")
            elif model.level is BatteryLevel.OK:
                found.note(f"battery charge {model.percentage:.0f} %")
            else:
                name = "critical" if model.level is BatteryLevel.CRITICAL else "low"
                found.fault(f"battery charge {model.percentage:.0f} % ({name})")
        return found
