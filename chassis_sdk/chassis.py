"""``Chassis``: the protocol A robot base, with SI units at the API."""

from __future__ import annotations

import datetime
import time
from collections.abc import Callable
from typing import Any

import anyio
import anyio.lowlevel

from ._device import Device
from ._dispatch import Subscription
from ._watchdog import FrameBuilder
from .diagnostics import Diagnosis, driver_findings, status_findings
from .errors import NotConnectedError, ProtocolError, RequestTimeoutError
from .events import StatusEdges
from .protocol._scale import check_duration, check_real
from .protocol.chassis import (
    REPLY_TO,
    ChassisDecoder,
    ChassisEncoder,
    ChassisInfo,
    ChassisMessage,
    ChassisStatus,
    CommandId,
    DriverStatus,
    DriveVelocity,
    FaultClear,
    FirmwareVersion,
    HardwareVersion,
    PowerTelemetry,
    ReplyId,
    ShipDate,
    Telemetry,
    velocity_command,
    wheel_speeds_command,
)

__all__ = ["Chassis"]

_ZERO = DriveVelocity(0, 0.0)


class Chassis(Device[ChassisMessage, ReplyId]):
    """A robot chassis speaking protocol A, over a serial port, pty or TCP socket.

    Constructing does no I/O. ``async with`` (or :meth:`connect`) opens the port and
    starts the background tasks; leaving it writes zero velocity, waits for it to leave,
    and closes the port, also on an exception or cancellation.

    Example:
        >>> async def main() -> None:  # doctest: +SKIP
        ...     async with Chassis("/dev/ttyUSB0") as robot:
        ...         print(await robot.get_chassis_info())
        ...         async for t in robot.telemetry():
        ...             print(t.voltage, t.linear, t.status)

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
        limits: Optional :class:`MotionLimits` (maximum speeds, acceleration and
            deceleration) applied to what the watchdog writes; stops are immediate.
        battery_low: Report ``BATTERY_LOW`` in :meth:`events` below this voltage
            (and ``BATTERY_OK`` 0.2 V above it); ``None`` (default) does not watch.
        connect_timeout: Seconds each open (and reconnect attempt) may take; the port
            is opened off the event loop, so nothing else waits for it.
        logger: Logger to use instead of ``logging.getLogger("chassis_sdk")``.

    Raises:
        ValueError: An option is out of range.
    """

    _decoder: ChassisDecoder

    def _init_protocol(self) -> None:
        self._encoder = ChassisEncoder()
        self._telemetry = self._stream()
        self._power = self._stream()
        self._latest: Telemetry | None = None
        self._latest_power: PowerTelemetry | None = None
        self._edges = StatusEdges()
        self._wheel_track: float | None = None  # effective track, when odometry uses wheels
        self._handlers = {
            Telemetry: self._on_telemetry,
            PowerTelemetry: self._on_power,
            DriverStatus: lambda m: self._resolve(ReplyId.DRIVER_STATUS, m),
            FirmwareVersion: lambda m: self._resolve(ReplyId.FIRMWARE_VERSION, m),
            HardwareVersion: lambda m: self._resolve(ReplyId.HARDWARE_VERSION, m),
            ChassisInfo: lambda m: self._resolve(ReplyId.CHASSIS_INFO, m),
            ShipDate: lambda m: self._resolve(ReplyId.SHIP_DATE, m),
        }

    # --- Device hooks -----------------------------------------------------------------------

    def _make_decoder(self) -> ChassisDecoder:
        return ChassisDecoder()

    def _sequence_gaps(self) -> int:
        return self._decoder.sequence.gaps

    @property
    def sequence_scheme(self) -> str | None:
        """How this chassis numbers its frames, as detected from them: ``"shared"``
        (one counter for every frame), ``"per-id"`` (one per frame id), or ``None``
        until enough frames have shown which (see ``LinkStats.sequence_gaps``)."""
        return self._decoder.sequence.scheme

    def _on_telemetry(self, t: Telemetry) -> None:
        self._latest = t
        self._telemetry.publish(t)
        for event in self._edges.update(t.status, t.docking, t.timestamp):
            self._emit(event)
        self._battery(t.voltage, t.timestamp)
        if self._wheel_track is None:
            self._integrate(t.linear, t.angular, t.timestamp)
        else:
            w = t.wheels
            left, right = (w.front_left + w.rear_left) / 2, (w.front_right + w.rear_right) / 2
            self._integrate((left + right) / 2, (right - left) / self._wheel_track, t.timestamp)

    def _on_power(self, p: PowerTelemetry) -> None:
        self._latest_power = p
        self._power.publish(p)

    def _on_link_up(self) -> None:
        self._decoder.sequence.reset()

    def _zero_frame(self) -> bytes:
        return self._encoder.encode(_ZERO)

    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        velocity_command(linear, angular)  # raises ValueError before anything is written
        encode = self._encoder.encode
        return lambda v, w: encode(velocity_command(v, w))

    async def configure_odometry(
        self,
        source: str = "velocity",
        *,
        track_width: float | None = None,
        slip_factor: float = 1.0,
        max_gap: float = 0.5,
    ) -> None:
        """Choose what :meth:`odometry` integrates.

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
        self._odometer.max_gap = max_gap
        self._wheel_track = track

    # --- motion (set_velocity and stop come from Device) ---------------------------------------

    async def set_wheel_speeds(
        self, left: float, right: float, *, duration: float | None = None
    ) -> None:
        """Drive in wheel mode: left and right side speeds in m/s.

        The front and rear wheel of a side turn alike. Watchdog, deadman and ``duration``
        behave as for :meth:`set_velocity`.

        Raises:
            ValueError: NaN, infinity, out of int16 mm/s range, or a bad ``duration``.
            NotConnectedError: The port is not open.
        """
        wheel_speeds_command(left, right)  # raises ValueError before anything is written
        encode = self._encoder.encode
        self._drive(
            (left, right),
            lambda a, b: encode(wheel_speeds_command(a, b)),
            check_duration(duration),
            f"wheels ({left}, {right})",
            "wheels",
        )
        await anyio.lowlevel.checkpoint()

    async def emergency_stop(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Engage the software emergency stop (0x03) and end any velocity command.

        The chassis reports it in ``Telemetry.status`` (``SOFTWARE_ESTOP``).

        Args:
            confirm: Return only once telemetry shows ``SOFTWARE_ESTOP``.
            timeout: Seconds to wait for that (with ``confirm``).

        Raises:
            RequestTimeoutError: ``confirm`` and the bit did not show in time.
        """
        self._ensure_connected()
        self._watchdog.clear()
        self._write(self._encoder.emergency_stop(True))
        await self.stop()
        if confirm:
            await self._confirm_bit(ChassisStatus.SOFTWARE_ESTOP, True, timeout)

    async def release_emergency_stop(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Release the software emergency stop (0x03, 0). The robot does not move until
        the next velocity command.

        Args:
            confirm: Return only once telemetry shows ``SOFTWARE_ESTOP`` cleared.
            timeout: Seconds to wait for that (with ``confirm``).
        """
        await self._send(self._encoder.emergency_stop(False))
        if confirm:
            await self._confirm_bit(ChassisStatus.SOFTWARE_ESTOP, False, timeout)

    async def clear_faults(
        self,
        *,
        driver: bool = True,
        front_bumper: bool = True,
        rear_bumper: bool = True,
        confirm: bool = False,
        timeout: float = 1.0,
    ) -> None:
        """Clear latched faults (0x05).

        Args:
            driver, front_bumper, rear_bumper: What to clear.
            confirm: Return only once telemetry shows the selected faults clear (a
                bumper still pressed, or a driver still failing, makes this time out).
            timeout: Seconds to wait for that (with ``confirm``).

        Raises:
            ValueError: Nothing selected to clear.
            RequestTimeoutError: ``confirm`` and a selected fault is still set.
        """
        what = FaultClear(0)
        bits = ChassisStatus(0)
        if driver:
            what |= FaultClear.DRIVER
            bits |= ChassisStatus.DRIVER_FAULT
        if front_bumper:
            what |= FaultClear.FRONT_BUMPER
            bits |= ChassisStatus.FRONT_BUMPER
        if rear_bumper:
            what |= FaultClear.REAR_BUMPER
            bits |= ChassisStatus.REAR_BUMPER
        if not what:
            raise ValueError("clear_faults() with nothing to clear: select at least one")
        await self._send(self._encoder.clear_faults(what))
        if confirm:
            await self._confirm(lambda t: not t.status & bits, timeout, f"{bits!r} clear")

    async def start_docking(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Start automatic docking (0x06, 1); follow ``Telemetry.docking``, or
        ``await robot.wait_for(lambda t: t.docking is DockingState.DOCKED, 60)``.

        Args:
            confirm: Return only once telemetry shows ``DOCKING_ENABLED``.
            timeout: Seconds to wait for that (with ``confirm``).
        """
        await self._send(self._encoder.docking(True))
        if confirm:
            await self._confirm_bit(ChassisStatus.DOCKING_ENABLED, True, timeout)

    async def stop_docking(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Stop automatic docking (0x06, 0).

        Args:
            confirm: Return only once telemetry shows ``DOCKING_ENABLED`` cleared.
            timeout: Seconds to wait for that (with ``confirm``).
        """
        await self._send(self._encoder.docking(False))
        if confirm:
            await self._confirm_bit(ChassisStatus.DOCKING_ENABLED, False, timeout)

    async def _confirm_bit(self, bit: ChassisStatus, present: bool, timeout: float) -> None:
        name = bit.name or repr(bit)
        await self._confirm(
            lambda t: (bit in t.status) is present,
            timeout,
            f"{name} set" if present else f"{name} cleared",
        )

    async def _confirm(
        self, predicate: Callable[[Telemetry], bool], timeout: float, what: str
    ) -> None:
        """Wait for a frame that arrived after the command and shows its effect."""
        sent = time.monotonic()
        try:
            await self.wait_for(lambda t: t.timestamp >= sent and predicate(t), timeout)
        except TimeoutError:
            raise RequestTimeoutError(
                f"{self.port}: telemetry did not show {what} within {timeout:g} s"
            ) from None

    async def wait_for(self, predicate: Callable[[Telemetry], bool], timeout: float) -> Telemetry:
        """Wait for telemetry that satisfies ``predicate`` and return it.

        The latest frame counts, so a condition that already holds returns at once.
        Example: ``await robot.wait_for(lambda t: t.docking is DockingState.DOCKED, 60)``.

        Args:
            predicate: Called with each :class:`Telemetry`.
            timeout: Seconds (finite); the wait always ends.

        Raises:
            TimeoutError: No frame satisfied ``predicate`` in time.
            ValueError: ``timeout`` is not a finite number > 0.
            ConnectionLostError: The link dropped (without ``reconnect``).
        """
        timeout = check_real(timeout, "timeout", low=0, low_open=True, unit="s")
        async with self.telemetry() as frames:
            latest = self._latest
            if latest is not None and predicate(latest):
                return latest
            with anyio.move_on_after(timeout):
                async for t in frames:
                    if predicate(t):
                        return t
                raise NotConnectedError(f"{self.port} was closed while waiting")
        raise TimeoutError(f"{self.port}: no telemetry satisfied the condition in {timeout:g} s")

    async def enable_telemetry(self, enabled: bool = True) -> None:
        """Switch the 50 Hz telemetry stream on or off (0x01). On at power-up."""
        await self._send(self._encoder.set_telemetry(enabled))

    async def enable_power_telemetry(self, enabled: bool = True) -> None:
        """Switch the 20 Hz driver current/voltage stream on or off (0xB1)."""
        await self._send(self._encoder.set_power_telemetry(enabled))

    # --- requests -------------------------------------------------------------------------------

    async def _read(self, what: CommandId) -> Any:
        reply = REPLY_TO[what]
        encoder = self._encoder
        return await self._request(
            lambda: (encoder.read(what), reply), read_only=True, what=f"{what.name} (0x{what:02X})"
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
        :meth:`get_firmware_version`."""
        reply: HardwareVersion = await self._read(CommandId.HARDWARE_VERSION)
        return reply.text

    async def get_chassis_info(self) -> ChassisInfo:
        """Read the geometry (0x09 → 0x89), lengths in metres. Raises as
        :meth:`get_firmware_version`."""
        reply: ChassisInfo = await self._read(CommandId.CHASSIS_INFO)
        return reply

    async def get_ship_date(self) -> datetime.date:
        """Read the ship date (0x0A → 0x8A).

        Raises:
            ProtocolError: The device sent an impossible date.
            RequestTimeoutError, ConnectionLostError, NotConnectedError: As for
                :meth:`get_firmware_version`.
        """
        reply: ShipDate = await self._read(CommandId.SHIP_DATE)
        try:
            return reply.to_date()
        except ValueError as exc:
            raise ProtocolError(f"device sent an invalid ship date {reply}: {exc}") from None

    async def get_driver_status(self) -> DriverStatus:
        """Read the four motor drivers' status (0xB0 → 0xB0). Raises as
        :meth:`get_firmware_version`."""
        reply: DriverStatus = await self._read(CommandId.DRIVER_STATUS)
        return reply

    async def diagnose(self) -> Diagnosis:
        """Gather the robot's health into one report: connection and link counters, every
        set status bit of the latest telemetry, and every error bit of each wheel's
        driver (read now with 0xB0, if connected). ``print()`` it for a readable report.

        Example:
            >>> report = await robot.diagnose()  # doctest: +SKIP
            >>> if not report.ok:  # doctest: +SKIP
            ...     print(report)
        """
        faults, notes = self._link_findings()
        latest = self._latest
        if latest is None:
            faults.append("no telemetry received")
        else:
            f, n = status_findings(latest.status)
            faults += f
            notes += n
            notes.append(f"battery {latest.voltage:.1f} V, docking {latest.docking.name}")
        scheme = self.sequence_scheme
        notes.append(
            "frame numbering: "
            + {"shared": "one counter for every frame", "per-id": "one counter per frame id"}.get(
                scheme or "", "not yet known"
            )
        )
        drivers = None
        if self.is_connected:
            try:
                drivers = await self.get_driver_status()
            except RequestTimeoutError:
                faults.append("driver status (0xB0) unanswered")
            else:
                f, n = driver_findings(drivers)
                faults += f
                notes += n
        return Diagnosis(
            "chassis",
            self.port,
            self._state,
            self.stats,
            tuple(faults),
            tuple(notes),
            None if latest is None else latest.status,
            drivers,
        )

    # --- streams --------------------------------------------------------------------------------

    def telemetry(self) -> Subscription[Telemetry]:
        """Subscribe to the 50 Hz telemetry: an async iterator of :class:`Telemetry`.

        Every subscriber gets every frame from the moment of the call; one that falls
        ``queue_size`` frames behind loses the oldest (counted in ``stats.queue_drops``).
        Breaking out of the loop unsubscribes. Without ``reconnect`` the iterator raises
        :class:`ConnectionLostError` when the link drops; it ends when the device closes.
        """
        return self._subscribe(self._telemetry)

    def power(self) -> Subscription[PowerTelemetry]:
        """Subscribe to the 20 Hz 0xB1 stream (after :meth:`enable_power_telemetry`)."""
        return self._subscribe(self._power)

    @property
    def latest_telemetry(self) -> Telemetry | None:
        """The most recent :class:`Telemetry`, or ``None`` before the first."""
        return self._latest

    @property
    def telemetry_age(self) -> float | None:
        """Seconds since the latest :class:`Telemetry` arrived, or ``None`` before the
        first. It keeps growing through an outage and a stale link."""
        latest = self._latest
        return None if latest is None else time.monotonic() - latest.timestamp

    @property
    def latest_power(self) -> PowerTelemetry | None:
        """The most recent :class:`PowerTelemetry`, or ``None``."""
        return self._latest_power
