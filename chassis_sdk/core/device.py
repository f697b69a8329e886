"""``Device``: what every device shares, composed of small collaborators.

A device is its protocol plus these, each in its own module and testable alone:

* [`Session`][chassis_sdk.core.session.Session] (the base): the port side, that is the
  link (`LinkSupervisor`: lifetime, writes, the
  close fence, reconnect, link health), requests
  (`Requester`), streams, recording, and the public
  observation API (taps and listeners);
* `Motion`: the velocity watchdog and the commands
  over it (deadman, ``duration``, limits and ramps);
* `Reports`: events, odometry, the battery watch.

A device package subclasses `Device` and implements its abstract methods (the
"hooks" below); everything else is here, once.
"""

from __future__ import annotations

import abc
import logging
import os
import time
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

import anyio
import anyio.lowlevel

from ..errors import NotConnectedError, ProtocolError, RequestTimeoutError
from .battery import BatteryModel
from .calibration import Calibration
from .diagnosis import Diagnosis, Findings
from .dispatch import Subscription
from .events import EventKind, RobotEvent
from .geometry import Geometry
from .motion import Axes, FrameBuilder, Motion, MotionLimits
from .motion.goal import MoveResult
from .motion.goals import Goals
from .motion.reflexes import ReflexRunner, back_off_on
from .motion.safety import SafetyPolicy
from .observation import Reports
from .odometry import Odometry
from .session import Recorder, Session, set_recorder
from .stats import LinkStats
from .supervisor import ConnectionState
from .validation import check_duration, check_int, check_optional, check_real

__all__ = ["ConnectionState", "Device", "LinkStats", "Recorder", "set_recorder"]

M = TypeVar("M")
K = TypeVar("K", bound=Hashable)
D = TypeVar("D", bound=Diagnosis)

_POSITIVE: dict[str, Any] = {"low": 0, "low_open": True}
_CONNECTING = ConnectionState.CONNECTING
#: States in which the link is gone: motion is blocked (``LINK_LOST``) until it is back.
_LINK_DOWN = frozenset({ConnectionState.RECONNECTING, ConnectionState.LOST})
#: Closing a recorded session that drove: the port stays open after the final zero
#: until a velocity sample shows the robot still (at most these m/s and rad/s: below
#: the wire's 1 mm/s), so the stop is in the recording; at most `SETTLE_LIMIT` s in
#: all, and no more than `SETTLE_QUIET` s without a sample (a device that reports no
#: motion).
STILL_LINEAR = 0.0005
STILL_ANGULAR = 0.005
SETTLE_LIMIT = 2.0
SETTLE_QUIET = 0.5
#: State -> the event entering it makes (CONNECTED only when coming back).
_LINK_EVENTS = {
    ConnectionState.STALE: EventKind.LINK_STALE,
    ConnectionState.RECONNECTING: EventKind.LINK_LOST,
    ConnectionState.LOST: EventKind.LINK_LOST,
    ConnectionState.CONNECTED: EventKind.LINK_RESTORED,
}


async def until_still(device: Device[Any, Any], log: logging.Logger) -> None:
    """Return once an odometry sample of ``device`` shows the robot still (at most
    `STILL_LINEAR`, `STILL_ANGULAR`), at most `SETTLE_LIMIT` s from now, and
    sooner when no sample has come for `SETTLE_QUIET` s (a device that reports no
    motion)."""
    still = anyio.Event()
    heard = time.monotonic()

    def sample(odometry: Odometry) -> None:
        nonlocal heard
        heard = odometry.timestamp
        if abs(odometry.linear) <= STILL_LINEAR and abs(odometry.angular) <= STILL_ANGULAR:
            still.set()

    listener = device.listen("odometry", sample)
    try:
        deadline = time.monotonic() + SETTLE_LIMIT
        while not still.is_set():
            now = time.monotonic()
            end = min(deadline, heard + SETTLE_QUIET)
            if now >= end:
                log.info("%s: closed before the robot showed still", device.port)
                return
            with anyio.move_on_after(end - now):
                await still.wait()
    finally:
        listener.close()


class Device(Session[M, K]):
    """Base of every device ([`Chassis`][chassis_sdk.Chassis], [`Board`][chassis_sdk.Board],
    and any a device package adds). See those classes for the arguments.

    ``M`` is the device's message type, ``K`` the key a reply is matched by.

    A subclass implements the hooks: `_make_decoder`, `_init_protocol`
    (its encoder, streams and `_handlers`), `_zero_frame` and
    `_velocity_builder`; it may override `_on_link_up`,
    `_sequence_gaps`, `_reply_quarantine` and `_on_odometry_reset`.
    From the base it uses `_stream`, `_send`, `_request`,
    `_reply`, `_drive`, `_emit`, `_battery`, `_charge`,
    `_integrate` and `_findings`.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 115200,
        request_timeout: float = 1.0,
        retries: int = 2,
        resend_interval: float = 0.05,
        command_timeout: float | None = 0.5,
        reconnect: bool = False,
        queue_size: int = 64,
        link_timeout: float | None = 1.0,
        limits: MotionLimits | None = None,
        battery_low: float | None = None,
        battery: BatteryModel | None = None,
        calibration: Calibration | None = None,
        connect_timeout: float = 2.0,
        close_linger: float = 5.0,
        logger: logging.Logger | None = None,
        record: str | os.PathLike[str] | None = None,
        read_only: bool = False,
        safety: SafetyPolicy | None = None,
    ) -> None:
        if not isinstance(port, str):
            raise TypeError(f"port must be a device path or URL string, got {port!r}")
        if not port:
            raise ValueError("port must be a device path or URL string, got ''")
        check_int(baudrate, "baudrate", low=1)
        request_timeout = check_real(request_timeout, "request_timeout", **_POSITIVE)
        check_int(retries, "retries", low=0)
        resend_interval = check_real(resend_interval, "resend_interval", **_POSITIVE)
        command_timeout = check_optional(command_timeout, "command_timeout", **_POSITIVE)
        self.queue_size = check_int(queue_size, "queue_size", low=1)
        link_timeout = check_optional(link_timeout, "link_timeout", **_POSITIVE)
        connect_timeout = check_real(connect_timeout, "connect_timeout", **_POSITIVE)
        close_linger = check_real(close_linger, "close_linger", low=0, unit="s")
        if battery is not None and not isinstance(battery, BatteryModel):
            raise TypeError(f"battery must be a BatteryModel or None, got {battery!r}")
        if calibration is not None and not isinstance(calibration, Calibration):
            raise TypeError(f"calibration must be a Calibration or None, got {calibration!r}")
        self._calibration = Calibration() if calibration is None else calibration
        log = logger if logger is not None else logging.getLogger("chassis_sdk")
        self._motion = Motion(
            self._write_velocity,
            self._ensure_connected,
            self._zero_frame,
            self._velocity_builder,
            interval=resend_interval,
            command_timeout=command_timeout,
            logger=log,
        )
        self._watchdog = self._motion.watchdog
        self._goals = Goals(self)
        reflexes = self._reflexes = ReflexRunner(
            self._motion,
            SafetyPolicy() if safety is None else safety,
            lambda event: self._emit(event),
            back_off=self._back_off,
            pose=lambda: self._reports.latest_odometry,
            acting=not read_only,
            logger=log,
        )
        self._watchdog.guard = lambda now, late: reflexes.link(self.last_frame_age, now, late)
        background = [("watchdog", self._watchdog.run)]
        if reflexes.needs_task:
            background.append(("reflexes", reflexes.run))
        super().__init__(
            port,
            baudrate=baudrate,
            request_timeout=request_timeout,
            retries=retries,
            reconnect=reconnect,
            queue_size=queue_size,
            link_timeout=link_timeout,
            connect_timeout=connect_timeout,
            close_linger=close_linger,
            logger=log,
            record=record,
            background=background,
            read_only=read_only,
        )
        self.limits = limits
        odometry = self._stream("odometry")  # the first named streams, in this order
        reports = self._reports = Reports(
            port, log, self._stream("events"), odometry, battery_low, battery
        )
        reports.calibration = self._calibration
        reports.reflexes = reflexes
        self._emit, self._battery = reports.emit, reports.battery
        self._charge, self._integrate = reports.charge, reports.integrate
        self._pose = reports.pose
        self._init_protocol()

    def _write_velocity(self, frame: bytes, expires: float) -> None:
        self._link.writer.write_velocity(frame, expires)

    # --- the hooks a device implements -----------------------------------------------------

    @abc.abstractmethod
    def _init_protocol(self) -> None:
        """Set up the encoder, streams and `_handlers` (end of ``__init__``)."""

    @abc.abstractmethod
    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        """Check ``(linear, angular)`` (raises ``ValueError``) and return a builder of
        velocity frames for any values between zero and them."""

    def _on_odometry_reset(self, heading: float) -> None:
        """A device with its own heading source resets it too."""

    def _sequence_gaps(self) -> int:
        """Breaks in the device's frame numbers (protocols that number frames)."""
        return 0

    def _closing_frame(self) -> bytes | None:
        motion = self._motion
        return self._zero_frame() if motion.zero_on_close or motion.watchdog.wrote else None

    def _on_fenced(self) -> None:
        self._motion.arbiter.stop()
        self._watchdog.clear()

    async def _settle(self) -> None:
        # Only a recording of a session that drove waits: a capture that ended at
        # the zero frame would hold the command to stop but not the stop.
        if self._recording is not None and not self.read_only and self._motion.watchdog.wrote:
            await until_still(self, self._log)

    def _on_state(self, old: ConnectionState, new: ConnectionState) -> None:
        if new in _LINK_DOWN:
            self._motion.set_blocks("link", ("LINK_LOST",))
        elif new is ConnectionState.CONNECTED:
            self._motion.set_blocks("link", ())
            self._reflexes.announce(time.monotonic())  # once: what the policy ignores
        kind = _LINK_EVENTS.get(new)
        if kind is not None and (new is not ConnectionState.CONNECTED or old is not _CONNECTING):
            self._emit(RobotEvent(kind, "", time.monotonic()))

    # --- motion -----------------------------------------------------------------------------------

    async def set_velocity(
        self, linear: float, angular: float, *, duration: float | None = None
    ) -> None:
        """Drive with a linear (m/s) and angular (rad/s) velocity.

        The frame is written at once (or, if a velocity frame left less than 20 ms
        ago, when that period is over: at most 50 a second reach the device) and
        re-sent every ``resend_interval``. Without ``duration`` it stays active until
        ``command_timeout`` after the *last* call (keep calling, as with ROS
        ``cmd_vel``); with ``duration`` it holds exactly that long. Then one zero frame
        is written. With `limits`, what is written is clamped and ramped towards the
        command; stopping is always immediate.

        The call is the application's source in the motion core (`motion`): it is
        refused while motion is blocked, and while a source of higher priority (a
        dashboard page, teleop) drives. A block ends the command, and clearing it
        restarts nothing: call again.

        Raises:
            ValueError: NaN, infinity, a value that overflows the wire field, or a bad
                ``duration``; nothing is written.
            MotionBlockedError: An e-stop, a latched bumper, a driver fault or a lost
                link blocks motion (``reasons`` names them), or another source drives;
                nothing is written.
            NotConnectedError: The port is not open.
        """
        build = self._velocity_builder(linear, angular)
        duration = check_duration(duration)
        self._drive((linear, angular), build, duration, "velocity")
        await anyio.lowlevel.checkpoint()

    def _drive(
        self,
        target: tuple[float, float],
        build: FrameBuilder,
        duration: float | None,
        axes: Axes,
    ) -> None:
        self._motion.drive(target[0], target[1], build, duration, axes)

    async def drive_distance(
        self,
        distance: float,
        speed: float | None = None,
        *,
        tolerance: float | None = None,
        timeout: float | None = None,
        kind: str = "goal",
    ) -> MoveResult:
        """Drive ``distance`` metres straight ahead (negative: backwards), closed on
        odometry, and stop; the heading is held on the line.

        The speed follows a trapezoid within `limits` (its accelerations and top
        speeds honoured): ``speed`` m/s at most (default 0.3), slowing to end within
        ``tolerance`` (default 1 cm) without overshooting. The goal is a source of the
        motion core (kind ``"goal"``, below the application's own velocities: a
        `set_velocity` ends it); a newer goal of the same ``kind`` replaces it. A
        surface that runs goals for its clients gives its own ``kind`` (``"mqtt"``),
        so its goals rank as its velocities do.

        Returns:
            The [`MoveResult`][chassis_sdk.MoveResult]: the pose at rest, the signed
            distance left, the duration, ``ended="done"``.

        Raises:
            TypeError, ValueError: A bad argument; nothing is written.
            MoveTimeoutError: Not done within ``timeout`` s; the robot is stopped.
            MotionBlockedError: An e-stop, a bumper, a driver fault, a lost link or
                no odometry ended it (or it could not start).
            MovePreemptedError: Another source took over, or a stop came.
            NotConnectedError: The port is not open.

        Cancelling the awaiting task writes a zero at once; nothing of the goal acts
        afterwards.
        """
        return await self._goals.drive_distance(distance, speed, tolerance, timeout, kind=kind)

    async def rotate(
        self,
        angle: float,
        rate: float | None = None,
        *,
        tolerance: float | None = None,
        timeout: float | None = None,
        kind: str = "goal",
    ) -> MoveResult:
        """Turn in place by ``angle`` radians (counter-clockwise positive, any size),
        closed on odometry's heading, at most ``rate`` rad/s (default 0.8), within
        ``tolerance`` (default 1°). Ends, returns and raises as `drive_distance`
        (``error`` in radians)."""
        return await self._goals.rotate(angle, rate, tolerance, timeout, kind=kind)

    async def go_to(
        self,
        x: float,
        y: float,
        heading: float | None = None,
        *,
        speed: float | None = None,
        tolerance: float | None = None,
        timeout: float | None = None,
        kind: str = "goal",
    ) -> MoveResult:
        """Go to the point ``(x, y)`` of the odometry frame (`reset_odometry` sets
        it): face it, drive the line to it, then turn to ``heading`` (radians) if
        given. Within ``tolerance`` (default 1 cm; the heading within 1°). Ends,
        returns and raises as `drive_distance` (``error``: metres to the point)."""
        return await self._goals.go_to(x, y, heading, speed, tolerance, timeout, kind=kind)

    async def _back_off(self, side: str, distance: float, speed: float, epoch: int) -> None:
        """A bumper reflex's back-off: ``_release_bumper``, then the distance away."""
        await back_off_on(
            self._motion, self._goals, side, distance, speed, self._release_bumper, epoch
        )

    async def _release_bumper(self, side: str) -> None:
        """Clear ``side``'s (``"front"``, ``"rear"``) bumper latch; a device with
        bumpers implements it (the base has none: nothing to clear)."""
        await anyio.lowlevel.checkpoint()

    @property
    def safety(self) -> SafetyPolicy:
        """The [`SafetyPolicy`][chassis_sdk.SafetyPolicy] its reflexes follow."""
        return self._reflexes.policy

    @property
    def last_reflex(self) -> RobotEvent | None:
        """The last reflex that acted (its ``REFLEX`` event), or ``None``."""
        return self._reflexes.last

    @property
    def reflexes_acted(self) -> dict[str, int]:
        """How many times each hazard's reflex acted since the start (``{"stall": 1}``)."""
        return dict(self._reflexes.count)

    def clear_reflexes(self) -> None:
        """Re-arm the reflexes that act once (a stall, the geofence, the link): each
        triggers again when next seen. A tilt or a critical battery blocks for as long
        as it lasts."""
        self._reflexes.clear()

    @property
    def motion(self) -> Motion:
        """The motion core: make a source to drive through (``robot.motion.source("my
        teleop", kind="teleop")``), set the priorities, see what blocks motion
        (``robot.motion.blocks``) and who drives (``robot.motion.driver``)."""
        return self._motion

    async def stop(self) -> None:
        """Write zero velocity now and end the active command.

        Raises:
            NotConnectedError: The port is not open (the command is ended anyway).
        """
        self._motion.stop()
        await anyio.lowlevel.checkpoint()

    @property
    def limits(self) -> MotionLimits:
        """The `MotionLimits` applied to what is written; assign to change them
        (the next write uses the new ones)."""
        return self._motion.limits

    @limits.setter
    def limits(self, limits: MotionLimits | None) -> None:
        self._motion.limits = limits

    @property
    def commanded_velocity(self) -> tuple[float, float] | None:
        """The active command as asked: ``(linear, angular)`` (``(left, right)`` in
        wheel mode), or ``None`` when no command is active."""
        return self._motion.commanded

    @property
    def written_velocity(self) -> tuple[float, float]:
        """What was last written for the active command, after limits and ramps
        (zeros when none is active)."""
        return self._watchdog.written

    @property
    def command_timeout(self) -> float | None:
        """The deadman (s): a velocity command without ``duration`` expires this long
        after the last call; ``None``: it holds until `stop`."""
        return self._watchdog.command_timeout

    # --- events, odometry, reports -------------------------------------------------------------

    def events(self) -> Subscription[RobotEvent]:
        """Subscribe to [`RobotEvent`][chassis_sdk.RobotEvent] edges: e-stops, bumpers, driver
        faults, docking changes (chassis), battery low/ok (with ``battery_low``, a
        voltage), battery low/critical/ok (with ``battery``, a state of charge), and
        the link going stale, lost and restored. Each edge is reported once.
        """
        return self._subscribe(self._reports.events)

    @property
    def battery_low(self) -> float | None:
        """Voltage below which ``BATTERY_LOW`` is reported (``None``: not watched)."""
        return self._reports.battery_monitor.threshold

    @property
    def battery_model(self) -> BatteryModel | None:
        """The state-of-charge estimator given as ``battery=`` (``None``: none)."""
        return self._reports.battery_model

    @property
    def battery_percentage(self) -> float | None:
        """The battery's estimated state of charge (0..100 %), or ``None``: no
        ``battery=`` model, or not known yet (warming up, or only readings under load
        with no current to correct them). Never a made-up number."""
        return self._reports.battery_percentage

    @property
    def calibration(self) -> Calibration:
        """The [`Calibration`][chassis_sdk.Calibration] applied to odometry and wheel-mode
        commands (``calibration=``; factors of 1 when none was given). Assign to change
        it: the next velocity sample and the next wheel-mode frame use the new one."""
        return self._calibration

    @calibration.setter
    def calibration(self, calibration: Calibration | None) -> None:
        if calibration is not None and not isinstance(calibration, Calibration):
            raise TypeError(f"calibration must be a Calibration or None, got {calibration!r}")
        self._calibration = Calibration() if calibration is None else calibration
        self._reports.calibration = self._calibration

    def odometry(self) -> Subscription[Odometry]:
        """Subscribe to the pose dead-reckoned from the device's reported velocities:
        an async iterator of [`Odometry`][chassis_sdk.Odometry], one per velocity sample.

        Integration runs all the time, subscribed or not, using the samples'
        timestamps, so irregular intervals and dropped frames do not bias it; a gap
        longer than half a second (an outage) is not integrated. See
        ``configure_odometry`` for the sources. The reported velocities are corrected
        by `calibration` first (``linear * linear_scale``, ``angular *
        angular_scale``), so the pose and the velocities of each sample are the
        calibrated ones; a heading from a gyro is the gyro's, uncorrected.
        """
        return self._subscribe(self._reports.odometry)

    @property
    def latest_odometry(self) -> Odometry | None:
        """The most recent [`Odometry`][chassis_sdk.Odometry], or ``None``."""
        return self._reports.latest_odometry

    def reset_odometry(self, x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> None:
        """Set the current pose (default: the origin, heading 0) and integrate from it.

        Raises:
            ValueError: A value is not finite.
        """
        heading = check_real(heading, "heading")
        x, y = check_real(x, "x"), check_real(y, "y")
        self._reports.reset_pose(x, y, heading)
        self._on_odometry_reset(heading)

    def motion_blocked(self) -> tuple[str, ...]:
        """What the device reports now that keeps it from moving (an e-stop, a bumper, a
        driver fault), by the names of the flags of its latest report; empty when
        nothing is known to block it (or the device reports no such thing). A command
        sent meanwhile is accepted and ignored by the firmware, so a caller can refuse
        to drive first (``chassis-sdk drive`` does)."""
        return ()

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link counters (see [`LinkStats`][chassis_sdk.LinkStats])."""
        link, requests, watchdog = self._link, self._requests, self._watchdog
        return LinkStats.of(
            self._decoder.stats,
            bytes_sent=link.writer.bytes_sent,
            frames_sent=link.writer.frames_sent,
            unmatched_replies=requests.unmatched,
            late_replies=requests.late,
            frames_discarded=link.discarded,
            queue_drops=self._streams.dropped,
            sequence_gaps=self._sequence_gaps(),
            reconnects=link.reconnects,
            resends=watchdog.resends,
            command_expiries=watchdog.expiries,
        )

    @property
    def last_frame_age(self) -> float | None:
        """Seconds since the last valid frame of any kind arrived (across reconnects),
        or ``None`` if none has."""
        last = self._link.last_frame_time
        return None if last is None else time.monotonic() - last

    async def geometry(self) -> Geometry | None:
        """The base's size (what the ROS 2 bridge's robot description is made from), as
        the device reports it; ``None`` for a device that does not (the default).

        Raises:
            RequestTimeoutError, ConnectionLostError, NotConnectedError: As the
                device's requests do, for a device that asks.
        """
        return None

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
                        f"{received} bytes arrived on {self.port} but none is a {self.device_name} "
                        "frame: is it another device, or the wrong baud rate?"
                    )
                raise RequestTimeoutError(
                    f"nothing arrived from {self.port} within {timeout:g} s (is the device "
                    "on, and is this its port?)"
                )
            await anyio.sleep(0.02)

    # `_emit`, `_battery`, `_charge` and `_integrate` are the `Reports` methods
    # themselves, bound in __init__: they run for every frame, and a method here that
    # only forwarded would cost a Python call per frame on the read path.

    #: Log an event and publish it on ``events``: ``_emit(event)``.
    _emit: Callable[[RobotEvent], None]
    #: A battery voltage (V) at a time, for ``battery_low``: ``_battery(voltage, timestamp)``.
    _battery: Callable[[float, float], None]
    #: A reading for the state of charge (``battery=``): the pack's voltage, the current
    #: it delivers if measured (else ``None``), the time, and whether it is under load
    #: when no current is known (see [`BatteryModel.update`][chassis_sdk.BatteryModel.update]):
    #: ``_charge(voltage, current, timestamp, loaded)``.
    _charge: Callable[..., None]
    #: One velocity sample (m/s, rad/s, s) into the pose, the calibration applied, with
    #: an absolute heading change instead of the angular velocity if the device has
    #: one: ``_integrate(linear, angular, timestamp, heading=None)``.
    _integrate: Callable[..., None]

    def _findings(self) -> Findings:
        """The link's and the battery's findings, for ``diagnose()`` to add to."""
        return self._reports.findings(self._link.state, self.last_frame_age)

    def _report(self, found: Findings, cls: type[D], **read: Any) -> D:
        """A [`Diagnosis`][chassis_sdk.Diagnosis] (``cls``: it or a device's subclass, with what was
        ``read`` for it) of these findings, now."""
        return cls(
            self.device_name,
            self.port,
            self._link.state,
            self.stats,
            tuple(found.faults),
            tuple(found.notes),
            **read,
        )
