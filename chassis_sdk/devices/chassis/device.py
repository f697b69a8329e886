"""``Chassis``: the protocol A robot base, with SI units at the API."""

from __future__ import annotations

import datetime
import time
from typing import Any

import anyio
import anyio.lowlevel

from ...core.dispatch import Broadcast, Subscription
from ...core.geometry import Geometry
from ...core.motion import FrameBuilder, frame_builder
from ...core.validation import check_duration, check_real
from ...errors import ProtocolError, RequestTimeoutError
from ..config import FromConfig
from .commands import ChassisCommands
from .health import (
    ChassisDiagnosis,
    StatusEdges,
    driver_findings,
    explain_status,
    status_findings,
)
from .messages import (
    ChassisInfo,
    ChassisStatus,
    CommandId,
    DriverStatus,
    DriveVelocity,
    DriveWheels,
    FirmwareVersion,
    HardwareVersion,
    PowerTelemetry,
    ReplyId,
    ShipDate,
    Telemetry,
)
from .protocol import (
    REPLY_TO,
    ChassisCommandDecoder,
    ChassisDecoder,
    ChassisEncoder,
    velocity_command,
    wheel_speeds_command,
)

__all__ = ["Chassis"]

_ZERO = DriveVelocity(0, 0.0)
#: Seconds a 0xB1 frame stands for the pack's current: while they come (20 Hz), the
#: state of charge is fed from them (voltage and currents of one instant), else from 0x81.
_POWER_FRESH = 0.25
#: Wheel speed (m/s) above which the pack counts as loaded when no current is known.
_MOVING = 0.02


#: Below this share of the other driver's voltage, a driver's reading is not the
#: pack's: the driver is offline or its sensor reads nothing.
_DRIVER_VOLTAGE_SHARE = 0.8


def _pack_voltage(p: PowerTelemetry) -> float:
    """The pack's voltage from the two drivers' readings (0xB1): their mean, or the
    higher one when the other is far below it (a driver that is offline reports 0 V,
    and the mean would be half the pack: a made-up charge)."""
    low, high = sorted((p.voltage_front, p.voltage_rear))
    return high if low < high * _DRIVER_VOLTAGE_SHARE else (low + high) / 2


class Chassis(ChassisCommands, FromConfig):
    """A robot chassis speaking protocol A, over a serial port, pty or TCP socket.

    Constructing does no I/O. ``async with`` (or [`connect`][chassis_sdk.Chassis.connect])
    opens the port and starts the background tasks; leaving it writes zero velocity,
    waits for it to leave, and closes the port, also on an exception or cancellation.

    Example:
        ```python
        async def main() -> None:
            async with Chassis("/dev/ttyUSB0") as robot:
                print(await robot.get_chassis_info())
                async for t in robot.telemetry():
                    print(t.voltage, t.linear, t.status)
        ```

    Args:
        port: Device path (``/dev/ttyUSB0``), pty path, or ``socket://host:port``.
        baudrate: Serial speed.
        request_timeout: Seconds to wait for each attempt of a request.
        retries: Extra attempts for read-only requests after a timeout.
        resend_interval: Watchdog period: the active velocity command is re-sent this
            often (s); the firmware stops the wheels after 0.5 s without one.
        command_timeout: Deadman (s): a velocity command without ``duration`` expires
            this long after the last call. ``None`` disables it (hold until stop()).
        reconnect: Reopen the port with backoff when the link drops, instead of failing.
        queue_size: Buffer per stream subscriber; on overflow the oldest is dropped.
        link_timeout: Seconds without a valid frame before the link is reported
            ``STALE`` (a state change, logged once); ``None`` disables the check.
        limits: Optional `MotionLimits` (maximum speeds, acceleration and
            deceleration) applied to what the watchdog writes; stops are immediate.
        battery_low: Report ``BATTERY_LOW`` in `events` below this voltage
            (and ``BATTERY_OK`` 0.2 V above it); ``None`` (default) does not watch.
        battery: A [`BatteryModel`][chassis_sdk.BatteryModel] (chemistry, cells, capacity,
            thresholds) for `battery_percentage` and the ``BATTERY_LOW``,
            ``BATTERY_CRITICAL`` and ``BATTERY_OK`` events of the state of charge.
            With power telemetry on (`enable_power_telemetry`), it is fed the
            0xB1 voltage and the sum of the wheel currents, so the sag under load is
            undone; without it, only the 0x81 voltages taken with the wheels still are
            used. ``None`` (default): no estimate (`battery_percentage` is
            ``None``).
        calibration: A [`Calibration`][chassis_sdk.Calibration] (``linear_scale``,
            ``angular_scale``, as ``chassis-sdk calibrate`` measures them): the
            velocities of 0x81 are multiplied by them before `odometry`
            integrates them, and `set_wheel_speeds` divides the speeds it writes
            by ``linear_scale``, so the wheels' true speed is the one asked for.
            `set_velocity` is written as the protocol defines it (the firmware
            turns it into wheel speeds with its own geometry; a closed loop over the
            calibrated odometry corrects it). `telemetry` stays what the chassis
            sent. ``None`` (default): factors of 1.
        connect_timeout: Seconds each open (and reconnect attempt) may take; the port
            is opened off the event loop, so nothing else waits for it.
        close_linger: Seconds the final zero of `close` may wait, in the
            background after ``close()`` has returned, for a device that has stopped
            reading (stale frames are discarded at once; the zero is the last frame it
            gets if it reads again within this bound). 0 discards it with the rest.
        logger: Logger to use instead of ``logging.getLogger("chassis_sdk")``.
        record: Record the session to this file while connected: ``.mcap`` (raw
            bytes both ways, every stream, the commands written, odometry and events;
            open it in Foxglove; needs the ``foxglove`` extra) or, any other name, a
            JSON-lines capture (raw bytes both ways). Everything the application and
            the watchdog write is in it, up to the zero frame of `close`, so a
            bug report is one file.
        read_only: A viewer: nothing is ever written to the device, not even the
            zero of `close`; commands and requests raise ``ChassisError``. For a
            monitor, a recorder or a read-only bridge of a robot someone else drives.
        safety: The [`SafetyPolicy`][chassis_sdk.SafetyPolicy] its reflexes follow
            (bumper, stall, tilt, geofence, battery, link: each ``stop`` by default;
            see docs/motion.md). ``None``: the default policy.

    Raises:
        TypeError: ``read_only`` is not a bool.
        ValueError: An option is out of range.
    """

    device_name = "chassis"
    _decoder: ChassisDecoder

    def _init_protocol(self) -> None:
        self._encoder = ChassisEncoder()
        self._telemetry: Broadcast[Telemetry] = self._stream("telemetry")
        self._power: Broadcast[PowerTelemetry] = self._stream("power")
        self._edges = StatusEdges()
        self._wheel_track: float | None = None  # effective track, when odometry uses wheels
        self._power_at = -float("inf")  # when the last 0xB1 arrived
        #: Until when (telemetry time) a SOFTWARE_ESTOP still shown after a release is
        #: taken for a frame sent before it; 0: no release pending.
        self._releasing = 0.0
        self._handlers = {
            Telemetry: self._on_telemetry,
            PowerTelemetry: self._on_power,
            DriverStatus: lambda m: self._reply(ReplyId.DRIVER_STATUS, m),
            FirmwareVersion: lambda m: self._reply(ReplyId.FIRMWARE_VERSION, m),
            HardwareVersion: lambda m: self._reply(ReplyId.HARDWARE_VERSION, m),
            ChassisInfo: lambda m: self._reply(ReplyId.CHASSIS_INFO, m),
            ShipDate: lambda m: self._reply(ReplyId.SHIP_DATE, m),
        }

    # --- Device hooks -----------------------------------------------------------------------

    def _make_decoder(self) -> ChassisDecoder:
        return ChassisDecoder()

    def _make_command_decoder(self) -> ChassisCommandDecoder:
        return ChassisCommandDecoder()

    def _sequence_gaps(self) -> int:
        return self._decoder.sequence.gaps

    @property
    def sequence_scheme(self) -> str | None:
        """How this chassis numbers its frames, as detected from them: ``"shared"``
        (one counter for every frame), ``"per-id"`` (one per frame id), or ``None``
        until enough frames have shown which (see ``LinkStats.sequence_gaps``)."""
        return self._decoder.sequence.scheme

    def _on_telemetry(self, t: Telemetry) -> None:
        # Every 0x81 (50 Hz) comes here. The usual frame (no status change, no battery
        # threshold) calls only the publish and the integration, each straight to the
        # code that does the work.
        self._telemetry.publish(t)
        ts = t.timestamp
        edges = self._edges
        if t.status != edges.bits or self._releasing:
            self._on_status(t)
        if t.status != edges.bits or t.docking is not edges.state:
            for event in edges.update(t.status, t.docking, ts):
                self._emit(event)
            # After the edges: the hit, then what the reflex did about it (the block
            # above already wrote the zero).
            status = t.status
            self._reflexes.bumpers(
                bool(status & ChassisStatus.FRONT_BUMPER),
                bool(status & ChassisStatus.REAR_BUMPER),
                ts,
            )
        reports = self._reports
        if reports.watches_voltage:
            self._battery(t.voltage, ts)
        if reports.battery_model is not None and ts - self._power_at > _POWER_FRESH:
            w = t.wheels
            moving = max(abs(w.front_left), abs(w.front_right), abs(w.rear_left), abs(w.rear_right))
            self._charge(t.voltage, None, ts, moving > _MOVING)
        if self._wheel_track is None:
            self._integrate(t.linear, t.angular, ts)
        else:
            w = t.wheels
            left, right = (w.front_left + w.rear_left) / 2, (w.front_right + w.rear_right) / 2
            self._integrate((left + right) / 2, (right - left) / self._wheel_track, ts)

    def _on_status(self, t: Telemetry) -> None:
        """Tell the motion core what the chassis reports blocks motion. For
        ``_RELEASE_GRACE`` s after `release_emergency_stop`, ``SOFTWARE_ESTOP`` in a
        frame is taken for one sent before the release took effect (the chassis may
        send a frame between the e-stop and its release, even after one without it),
        not for a new e-stop: only this host engages it. Still shown after that, it
        blocks."""
        flags = self.motion_blocked()
        if self._releasing:
            if t.timestamp < self._releasing:
                flags = tuple(f for f in flags if f != "SOFTWARE_ESTOP")
            else:
                self._releasing = 0.0
        self._motion.set_blocks("device", flags)

    def _on_power(self, p: PowerTelemetry) -> None:
        self._power.publish(p)
        if self.battery_model is not None:
            self._power_at = p.timestamp
            # The pack delivers what the four drivers draw: the sum of their magnitudes
            # (a driver's sign is the torque's direction, not the pack's).
            current = sum(abs(c) for c in p.currents)
            self._charge(_pack_voltage(p), current, p.timestamp)

    async def _release_bumper(self, side: str) -> None:
        await self.clear_faults(
            driver=False, front_bumper=side == "front", rear_bumper=side == "rear"
        )

    def _on_link_up(self) -> None:
        self._decoder.sequence.reset()

    def _zero_frame(self) -> bytes:
        return self._encoder.encode(_ZERO)

    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        return frame_builder(velocity_command, self._encoder.encode, linear, angular)

    async def configure_odometry(
        self,
        source: str = "velocity",
        *,
        track_width: float | None = None,
        slip_factor: float = 1.0,
        max_gap: float = 0.5,
    ) -> None:
        """Choose what [`odometry`][chassis_sdk.Chassis.odometry] integrates.

        Args:
            source: ``"velocity"`` (default): the chassis's own linear and angular
                velocity from 0x81. ``"wheels"``: the four wheel speeds, with the
                angular velocity from the left/right difference over the effective
                track, ``track_width * slip_factor``.
            track_width: Metres; ``None`` reads it from the chassis (0x09).
            slip_factor: Skid-steer slip (>= 1): how much wider the effective track is
                than the geometric one, because the wheels skid in a turn. Calibrate by
                turning in place a measured angle.
            max_gap: Longest interval between samples that is integrated (s).

        Raises:
            ValueError: An unknown source, or a value out of range.
            RequestTimeoutError: ``track_width`` was not given and 0x09 went unanswered.
        """
        if source not in ("velocity", "wheels"):
            raise ValueError(f"source must be 'velocity' or 'wheels', got {source!r}")
        slip_factor = check_real(slip_factor, "slip_factor", low=1)
        if track_width is not None:
            track_width = check_real(track_width, "track_width", low=0, low_open=True, unit="m")
        max_gap = check_real(max_gap, "max_gap", low=0, low_open=True, unit="s")
        track: float | None = None
        if source == "wheels":
            if track_width is None:
                track_width = (await self.get_chassis_info()).track_width
            track = track_width * slip_factor
        self._pose.max_gap = max_gap
        self._wheel_track = track

    # --- motion (set_velocity and stop come from Device) ---------------------------------------

    async def set_wheel_speeds(
        self, left: float, right: float, *, duration: float | None = None
    ) -> None:
        """Drive in wheel mode: left and right side speeds in m/s.

        The front and rear wheel of a side turn alike. Watchdog, deadman and ``duration``
        behave as for `set_velocity`. The speeds are true ones: what is written is
        each divided by ``calibration.linear_scale`` (the wheels' real diameter), after
        `limits` (which, like `commanded_velocity`, see the speeds asked).

        Raises:
            ValueError: NaN, infinity, out of int16 mm/s range, or a bad ``duration``.
            NotConnectedError: The port is not open.
        """
        scale = self.calibration.linear_scale
        if scale == 1.0:
            make = wheel_speeds_command
        else:

            def make(left: float, right: float) -> DriveWheels:
                return wheel_speeds_command(left / scale, right / scale)

        build = frame_builder(make, self._encoder.encode, left, right)
        self._drive((left, right), build, check_duration(duration), "wheels")
        await anyio.lowlevel.checkpoint()

    # --- requests -------------------------------------------------------------------------------

    async def _read(self, request: CommandId) -> Any:
        reply = REPLY_TO[request]
        encoder = self._encoder
        return await self._request(
            lambda: (encoder.read(request), reply),
            read_only=True,
            name=f"{request.name} (0x{request:02X})",
        )

    async def get_firmware_version(self) -> int:
        """Read the firmware version number (0x07 → 0x87).

        Raises:
            RequestTimeoutError: No reply within ``request_timeout`` on any attempt.
            ConnectionLostError: The link dropped while waiting.
            NotConnectedError: The port is not open.
        """
        reply: FirmwareVersion = await self._read(CommandId.FIRMWARE_VERSION)
        return reply.version

    async def get_hardware_version(self) -> str:
        """Read the hardware version string (0x08 → 0x88). Raises as
        [`get_firmware_version`][chassis_sdk.Chassis.get_firmware_version]."""
        reply: HardwareVersion = await self._read(CommandId.HARDWARE_VERSION)
        return reply.text

    async def get_chassis_info(self) -> ChassisInfo:
        """Read the geometry (0x09 → 0x89), lengths in metres. Raises as
        [`get_firmware_version`][chassis_sdk.Chassis.get_firmware_version]."""
        reply: ChassisInfo = await self._read(CommandId.CHASSIS_INFO)
        return reply

    async def geometry(self) -> Geometry:
        """The base's size from `get_chassis_info` (its four wheels, the radius half the
        diameter). Raises as `get_firmware_version`."""
        info = await self.get_chassis_info()
        return Geometry(info.track_width, info.wheelbase, info.wheel_diameter / 2)

    async def get_ship_date(self) -> datetime.date:
        """Read the ship date (0x0A → 0x8A).

        Raises:
            ProtocolError: The device sent an impossible date.
            RequestTimeoutError, ConnectionLostError, NotConnectedError: As for
                [`get_firmware_version`][chassis_sdk.Chassis.get_firmware_version].
        """
        reply: ShipDate = await self._read(CommandId.SHIP_DATE)
        try:
            return reply.to_date()
        except ValueError as exc:
            raise ProtocolError(f"device sent an invalid ship date {reply}: {exc}") from None

    async def get_driver_status(self) -> DriverStatus:
        """Read the four motor drivers' status (0xB0 → 0xB0). Raises as
        [`get_firmware_version`][chassis_sdk.Chassis.get_firmware_version]."""
        reply: DriverStatus = await self._read(CommandId.DRIVER_STATUS)
        return reply

    async def diagnose(self) -> ChassisDiagnosis:
        """Gather the robot's health into one report: connection and link counters, every
        set status bit of the latest telemetry, and every error bit of each wheel's
        driver (read now with 0xB0, if connected and not ``read_only``). ``print()`` it
        for a readable report.

        Example:
            ```python
            report = await robot.diagnose()
            if not report.ok:
                print(report)
            ```
        """
        found = self._findings()
        latest = self._telemetry.latest
        if latest is None:
            found.fault("no telemetry received")
        else:
            status_findings(latest.status, found)
            found.note(f"battery {latest.voltage:.1f} V, docking {latest.docking.name}")
        scheme = {"shared": "one counter for every frame", "per-id": "one counter per frame id"}
        found.note(f"frame numbering: {scheme.get(self.sequence_scheme or '', 'not yet known')}")
        drivers = None
        if self.read_only:  # a viewer asks nothing: 0xB0 is a request
            found.note("driver status not read (read-only)")
        elif self.is_connected:
            try:
                drivers = await self.get_driver_status()
            except RequestTimeoutError:
                found.fault("driver status (0xB0) unanswered")
            else:
                driver_findings(drivers, found)
        status = None if latest is None else latest.status
        return self._report(found, ChassisDiagnosis, status=status, drivers=drivers)

    # --- streams --------------------------------------------------------------------------------

    def telemetry(self) -> Subscription[Telemetry]:
        """Subscribe to the 50 Hz telemetry: an async iterator of `Telemetry`.

        Every subscriber gets every frame from the moment of the call; one that falls
        ``queue_size`` frames behind loses the oldest (counted in ``stats.queue_drops``).
        Breaking out of the loop unsubscribes. Without ``reconnect`` the iterator raises
        `ConnectionLostError` when the link drops; it ends when the device closes.
        """
        return self._subscribe(self._telemetry)

    def power(self) -> Subscription[PowerTelemetry]:
        """Subscribe to the 20 Hz 0xB1 stream (after `enable_power_telemetry`)."""
        return self._subscribe(self._power)

    @property
    def latest_telemetry(self) -> Telemetry | None:
        """The most recent `Telemetry`, or ``None`` before the first."""
        return self._telemetry.latest

    def motion_blocked(self) -> tuple[str, ...]:
        """The latest telemetry's status flags that stop the wheels: the e-stops
        (``SOFTWARE_ESTOP``, ``HARDWARE_ESTOP``, ``REMOTE_ESTOP``), a latched bumper,
        a driver error or a driver offline (the faults of
        `FAULT_STATUS`), lowest bit first;
        empty when none is set or before the first telemetry."""
        latest = self._telemetry.latest
        if latest is None:
            return ()
        return tuple(flag.name for flag in explain_status(latest.status) if flag.fault)

    @property
    def telemetry_age(self) -> float | None:
        """Seconds since the latest `Telemetry` arrived, or ``None`` before the
        first. It keeps growing through an outage and a stale link."""
        latest = self._telemetry.latest
        return None if latest is None else time.monotonic() - latest.timestamp

    @property
    def latest_power(self) -> PowerTelemetry | None:
        """The most recent `PowerTelemetry`, or ``None``."""
        return self._power.latest
