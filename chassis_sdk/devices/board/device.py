"""``Board``: the protocol B controller board (IMU, LED, buzzer, motors, servos)."""

from __future__ import annotations

import math

import anyio
import anyio.lowlevel

from ...core.device import Device
from ...core.diagnosis import Diagnosis
from ...core.dispatch import Broadcast, Subscription
from ...core.motion import FrameBuilder, frame_builder
from ...core.validation import check_real
from ...errors import ChassisError, RequestTimeoutError
from ..config import FromConfig
from .messages import (
    BatteryReading,
    BoardMessage,
    BoardType,
    BuzzerCommand,
    BuzzerReply,
    ImuSample,
    ImuScale,
    LedCommand,
    LedReply,
    LogMessage,
    SwitchAction,
    VelocityCommand,
    VelocityFeedback,
)
from .protocol import (
    BoardCommandDecoder,
    BoardDecoder,
    BoardEncoder,
    motor_pwm_command,
    servo_command,
    velocity_command,
)

__all__ = ["ID_QUARANTINE", "Board"]

#: Seconds (at least; ten request timeouts if longer) a request id whose request timed
#: out stays retired, unless its late reply arrives first.
ID_QUARANTINE = 30.0

_ZERO = VelocityCommand(0, 0)
_Key = tuple[BoardType, int]


class Board(Device[BoardMessage, _Key], FromConfig):
    """A controller board speaking protocol B, over a serial port, pty or TCP socket.

    Lifetime, options, the velocity watchdog and the deadman are exactly those of
    [`Chassis`][chassis_sdk.Chassis].

    IMU samples are in g and °/s by the vendor document's scale (164 counts per g, 16.4
    per °/s), with the raw counts in ``ImuSample.raw`` and SI values in
    ``linear_acceleration`` (m/s²) and ``angular_velocity`` (rad/s). A board whose IMU
    counts differently gets its own scale: ``board.imu_scale = ImuScale(16384, 65.5)``.

    LED and buzzer requests carry a one-byte request id that the board copies into its
    reply. Ids are allocated round-robin, skipping any in use, so up to 256 requests
    may be outstanding and replies may come back in any order. An id whose request
    timed out is retired until its late reply arrives (and is dropped) or
    `ID_QUARANTINE` seconds pass, so a late reply never answers a later request.

    With ``battery=BatteryModel(...)``, `battery_percentage` is estimated from
    the 0x13 voltage (1 Hz); the board reports no current, so readings taken while it
    moves are not used (the default ``warmup`` wants 5 readings: 5 s at rest).

    With ``calibration=Calibration(...)``, the velocities of 0x12 are multiplied by its
    ``linear_scale`` and ``angular_scale`` before `odometry` integrates them
    (`velocity` stays what the board sent). Velocity commands (0x22) are written
    as the protocol defines them: the board has no wheel mode. With
    ``configure_odometry(heading="imu")`` the heading is the gyro's, which needs no
    angular factor; ``chassis-sdk calibrate PORT angular`` fits that factor from the
    gyro for the velocity heading.

    ``safety=SafetyPolicy(...)`` sets its reflexes (a tilt or an impact seen by the
    IMU stops it by default; see docs/motion.md).

    Example:
        ```python
        async def main() -> None:
            async with Board("/dev/ttyUSB0") as board:
                await board.set_led(True)
                async for sample in board.imu():
                    print(sample.accel.z)
        ```
    """

    #: The angles :meth:`set_servo` takes, in degrees. The vendor document gives only
    #: the resolution (0.1°, an int16 on the wire: ±3276.7°); 0 to 180° is a hobby
    #: servo's travel, so 400° is refused rather than driven into the end stop. A
    #: subclass (or an instance) for another servo sets its own.
    servo_range: tuple[float, float] = (0.0, 180.0)

    device_name = "board"

    def _init_protocol(self) -> None:
        self._encoder = BoardEncoder()
        self._next_id = 0
        self._imu: Broadcast[ImuSample] = self._stream("imu")
        self._velocity: Broadcast[VelocityFeedback] = self._stream("velocity")
        self._battery_stream: Broadcast[BatteryReading] = self._stream("battery")
        self._logs: Broadcast[str] = self._stream("logs")
        self._gyro_heading: float | None = None  # unwrapped, rad, when heading="imu"
        self._last_imu_time: float | None = None
        self._handlers = {
            ImuSample: self._on_imu,
            VelocityFeedback: self._on_velocity,
            BatteryReading: self._on_battery,
            LogMessage: self._on_log,
            LedReply: lambda m: self._reply((BoardType.LED, m.request_id), m),
            BuzzerReply: lambda m: self._reply((BoardType.BUZZER, m.request_id), m),
        }
        self._imu_scale: ImuScale | None = None  # None: the decoder's, the document's

    # --- Device hooks -----------------------------------------------------------------------

    def _make_decoder(self) -> BoardDecoder:
        return BoardDecoder()

    def _make_command_decoder(self) -> BoardCommandDecoder:
        return BoardCommandDecoder()

    def _on_imu(self, m: ImuSample) -> None:
        if self._imu_scale is not None and m.raw is not None:
            m = m.scaled(self._imu_scale)
        self._imu.publish(m)
        a = m.accel
        self._reflexes.imu(a.x, a.y, a.z, m.timestamp)
        if self._gyro_heading is not None:
            last, self._last_imu_time = self._last_imu_time, m.timestamp
            if last is not None and 0 < m.timestamp - last <= self._pose.max_gap:
                self._gyro_heading += math.radians(m.gyro.z) * (m.timestamp - last)

    def _on_velocity(self, m: VelocityFeedback) -> None:
        self._velocity.publish(m)
        self._integrate(m.linear, m.angular, m.timestamp, self._gyro_heading)

    def _on_odometry_reset(self, heading: float) -> None:
        if self._gyro_heading is not None:
            self._gyro_heading = heading

    async def configure_odometry(self, heading: str = "velocity", *, max_gap: float = 0.5) -> None:
        """Choose what [`odometry`][chassis_sdk.Board.odometry] takes its heading from.

        Args:
            heading: ``"velocity"`` (default): integrate the angular velocity of 0x12.
                ``"imu"``: integrate the gyro's z rate from 0x11 (100 Hz), which sees
                wheel slip that the velocity feedback does not.
            max_gap: Longest interval between samples that is integrated (s).

        Raises:
            ValueError: An unknown heading source or a bad ``max_gap``.
        """
        if heading not in ("velocity", "imu"):
            raise ValueError(f"heading must be 'velocity' or 'imu', got {heading!r}")
        max_gap = check_real(max_gap, "max_gap", low=0, low_open=True, unit="s")
        self._pose.max_gap = max_gap
        self._gyro_heading = self._pose.heading if heading == "imu" else None
        self._last_imu_time = None
        await anyio.lowlevel.checkpoint()

    def _on_battery(self, m: BatteryReading) -> None:
        self._battery_stream.publish(m)
        self._battery(m.voltage, m.timestamp)
        if self.battery_model is not None:
            # The board measures no current: a reading taken while it moves is not
            # used for the state of charge (the sag would count as discharge).
            v = self._velocity.latest
            loaded = v is not None and (abs(v.linear) > 0.02 or abs(v.angular) > 0.05)
            self._charge(m.voltage, None, m.timestamp, loaded=loaded)

    def _on_log(self, m: LogMessage) -> None:
        self._log.debug("%s: board log: %s", self.port, m.text)
        self._logs.publish(m.text)

    def _zero_frame(self) -> bytes:
        return self._encoder.encode(_ZERO)

    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        return frame_builder(velocity_command, self._encoder.encode, linear, angular)

    # --- commands without a reply -------------------------------------------------------------

    async def set_motor_pwm(self, motor: int, pwm: int) -> None:
        """Set one motor's raw PWM value (0x21, for testing the drive train).

        Args:
            motor: A `Motor` (1 rear-left, 2 rear-right,
                3 front-left, 4 front-right).
            pwm: Signed PWM value (int16).

        Raises:
            ValueError: Unknown motor or PWM out of int16 range; nothing is written.
        """
        await self._send(self._encoder.encode(motor_pwm_command(motor, pwm)))

    async def set_servo(self, servo: int, angle: float) -> None:
        """Move a servo (0x31) to ``angle`` degrees (0.1° resolution), within
        `servo_range` (0 to 180°).

        Raises:
            TypeError: ``servo`` is not an ``int`` or ``angle`` not a number.
            ValueError: Unknown servo (not 1 or 2), or an angle outside
                `servo_range`; nothing is written.
        """
        angle = check_real(angle, "angle", unit="degrees")
        low, high = self.servo_range
        if not low <= angle <= high:
            raise ValueError(
                f"angle={angle:g} degrees is out of range: the servo takes {low:g} to {high:g}"
            )
        await self._send(self._encoder.encode(servo_command(servo, angle)))

    # --- requests -------------------------------------------------------------------------------

    def _reply_quarantine(self) -> float:
        return max(ID_QUARANTINE, 10 * self.request_timeout)

    def _allocate_id(self) -> int:
        """The next request id free for both LED and buzzer (so a stray reply can never
        be taken for another kind's), round-robin, skipping ids in use or retired.

        Raises:
            ChassisError: All 256 are in use or retired.
        """
        for _ in range(256):
            rid = self._next_id
            self._next_id = (rid + 1) & 0xFF
            if self._id_free(rid):
                return rid
        raise ChassisError(
            f"{self.port}: all 256 request ids are in flight or retired after timeouts; "
            "is the board answering?"
        )

    def _id_free(self, rid: int) -> bool:
        free = self._requests.table.is_free
        return free((BoardType.LED, rid)) and free((BoardType.BUZZER, rid))

    async def _switch(self, kind: BoardType, action: SwitchAction) -> bool:
        cls = LedCommand if kind is BoardType.LED else BuzzerCommand
        encode = self._encoder.encode

        def build() -> tuple[bytes, _Key]:
            rid = self._allocate_id()
            return encode(cls(action, rid)), (kind, rid)

        # Up to 256 requests are in flight; more wait for an id to come free.
        wait = self.request_timeout * (self.retries + 1)
        with anyio.move_on_after(wait) as scope:
            while not any(map(self._id_free, range(256))):
                self._ensure_connected()
                await self._requests.table.released(self.request_timeout)
        if scope.cancelled_caught:
            raise RequestTimeoutError(
                f"{self.port}: no request id came free within {wait:g} s (256 in flight "
                "or retired after timeouts; is the board answering?)"
            )
        reply: LedReply | BuzzerReply = await self._request(
            build, read_only=action is SwitchAction.READ, name=f"{kind.name} {action.name}"
        )
        return reply.on

    async def set_led(self, on: bool) -> bool:
        """Switch the LED; return the state the board reports afterwards.

        Raises:
            RequestTimeoutError: No reply within ``request_timeout``.
            ConnectionLostError, NotConnectedError: The link is down.
        """
        return await self._switch(BoardType.LED, SwitchAction.ON if on else SwitchAction.OFF)

    async def get_led(self) -> bool:
        """Read the LED state (retried up to ``retries`` times)."""
        return await self._switch(BoardType.LED, SwitchAction.READ)

    async def set_buzzer(self, on: bool) -> bool:
        """Switch the buzzer; return the state the board reports afterwards."""
        return await self._switch(BoardType.BUZZER, SwitchAction.ON if on else SwitchAction.OFF)

    async def get_buzzer(self) -> bool:
        """Read the buzzer state (retried up to ``retries`` times)."""
        return await self._switch(BoardType.BUZZER, SwitchAction.READ)

    async def diagnose(self) -> Diagnosis:
        """Gather the board's health into one report: connection and link counters, the
        battery, an IMU plausibility check (about 1 g at rest or cruising) and the LED
        and buzzer states (read now, if connected). ``print()`` it to read it."""
        found = self._findings()
        battery = self._battery_stream.latest
        found.note(
            "battery: no reading yet" if battery is None else f"battery {battery.voltage:.2f} V"
        )
        imu = self._imu.latest
        if imu is None:
            found.fault("no IMU sample received")
        else:
            g = math.sqrt(imu.accel.x**2 + imu.accel.y**2 + imu.accel.z**2)
            (found.note if 0.8 <= g <= 1.2 else found.fault)(f"IMU reads |a| = {g:.2f} g")
        if self.is_connected:
            for name, read in (("LED", self.get_led), ("buzzer", self.get_buzzer)):
                try:
                    found.note(f"{name} {'on' if await read() else 'off'}")
                except RequestTimeoutError:
                    found.fault(f"{name} request unanswered")
        return self._report(found, Diagnosis)

    # --- streams --------------------------------------------------------------------------------

    def imu(self) -> Subscription[ImuSample]:
        """Subscribe to IMU samples (0x11): accelerometer, gyroscope, magnetometer."""
        return self._subscribe(self._imu)

    def velocity(self) -> Subscription[VelocityFeedback]:
        """Subscribe to velocity feedback (0x12), m/s and rad/s."""
        return self._subscribe(self._velocity)

    def battery(self) -> Subscription[BatteryReading]:
        """Subscribe to battery readings (0x13), volts."""
        return self._subscribe(self._battery_stream)

    def logs(self) -> Subscription[str]:
        """Subscribe to the board's log lines (0xF1)."""
        return self._subscribe(self._logs)

    @property
    def imu_scale(self) -> ImuScale:
        """The IMU's counts per g and per °/s applied to `imu` samples (and to the
        ``diagnose()`` check); assign to change it."""
        return self._imu_scale if self._imu_scale is not None else ImuScale()

    @imu_scale.setter
    def imu_scale(self, scale: ImuScale) -> None:
        if not isinstance(scale, ImuScale):
            raise TypeError(f"imu_scale must be an ImuScale, got {scale!r}")
        self._imu_scale = None if scale == ImuScale() else scale

    @property
    def latest_imu(self) -> ImuSample | None:
        """The most recent `ImuSample`, or ``None``."""
        return self._imu.latest

    @property
    def latest_velocity(self) -> VelocityFeedback | None:
        """The most recent `VelocityFeedback`, or ``None``."""
        return self._velocity.latest

    @property
    def latest_battery(self) -> BatteryReading | None:
        """The most recent `BatteryReading`, or ``None``."""
        return self._battery_stream.latest
