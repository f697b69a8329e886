"""Protocol B (the controller board): the typed messages and the enums of their fields.

Frozen, slotted dataclasses (and ``NamedTuple``s where a value is a plain tuple of
numbers), in SI units; the wire format is `.protocol`'s business.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple, TypeAlias

from ...core.construct import fast_repr
from ...core.enums import NamedEnum
from ...core.validation import check_real

__all__ = [
    "STANDARD_GRAVITY",
    "BatteryReading",
    "BoardCommand",
    "BoardMessage",
    "BoardType",
    "BuzzerCommand",
    "BuzzerReply",
    "ImuCounts",
    "ImuSample",
    "ImuScale",
    "LedCommand",
    "LedReply",
    "LogMessage",
    "Motor",
    "MotorPwmCommand",
    "Servo",
    "ServoCommand",
    "SwitchAction",
    "Vector3",
    "VelocityCommand",
    "VelocityFeedback",
]


class BoardType(IntEnum):
    """Message types of protocol B (both directions)."""

    LED = 0x01  #: LED command (host) or LED state reply (board)
    BUZZER = 0x02  #: buzzer command (host) or buzzer state reply (board)
    IMU = 0x11  #: IMU sample: accelerometer, gyroscope, magnetometer
    VELOCITY_FEEDBACK = 0x12  #: measured linear and angular velocity
    BATTERY = 0x13  #: battery voltage
    MOTOR_PWM = 0x21  #: raw PWM for one motor (test use)
    VELOCITY = 0x22  #: velocity command
    SERVO = 0x31  #: servo angle command
    LOG = 0xF1  #: a line of log text


class SwitchAction(IntEnum):
    """The command byte of an LED or buzzer request."""

    OFF = 0  #: switch off
    ON = 1  #: switch on
    READ = 2  #: only report the state


class Motor(NamedEnum):
    """Motor numbers of the 0x21 PWM command."""

    REAR_LEFT = 1  #: rear-left wheel
    REAR_RIGHT = 2  #: rear-right wheel
    FRONT_LEFT = 3  #: front-left wheel
    FRONT_RIGHT = 4  #: front-right wheel


class Servo(NamedEnum):
    """Servo channels of the 0x31 servo command."""

    FIRST = 1  #: servo channel 1
    SECOND = 2  #: servo channel 2


@fast_repr
class Vector3(NamedTuple):
    """Three axes of one sensor."""

    x: float
    y: float
    z: float


#: Standard gravity (m/s² per g), for SI accelerations.
STANDARD_GRAVITY = 9.80665


@fast_repr
class ImuCounts(NamedTuple):
    """The 0x11 frame's nine int16 counts, exactly as the board sent them."""

    accel_x: int
    accel_y: int
    accel_z: int
    gyro_x: int
    gyro_y: int
    gyro_z: int
    mag_x: int
    mag_y: int
    mag_z: int


@fast_repr
@dataclass(frozen=True, slots=True)
class ImuScale:
    """How many counts the board's IMU reports per unit.

    The defaults are the vendor document's: accel / 164.0, gyro / 16.4. 16.4 counts per
    °/s is the ±2000 °/s range of common MEMS gyros. 164 counts per g matches no standard
    accelerometer range (a ±2 g part reads 16384 per g, ±16 g 2048): it is a unit the
    firmware defines, and the simulator follows the document. A public driver for this
    board family uses ``ImuScale(accel=16384.0, gyro=65.5)``; if at rest ``|accel|`` is
    not about 1, measure yours and pass it to ``Board(imu_scale=...)``.

    Attributes:
        accel: Counts per g.
        gyro: Counts per degree per second.
    """

    accel: float = 164.0
    gyro: float = 16.4

    def __post_init__(self) -> None:
        for name in ("accel", "gyro"):
            check_real(getattr(self, name), f"imu scale {name}", low=0, low_open=True)


@fast_repr
@dataclass(frozen=True, slots=True)
class ImuSample:
    """The 0x11 IMU frame.

    Attributes:
        accel: Acceleration in g: the raw counts over the scale (164 per g by default,
            the vendor document's; see `ImuSample.scaled` and ``ImuScale``).
        gyro: Angular rate in degrees per second (raw / 16.4 by default).
        mag: Magnetic field, raw counts (the document gives no scale).
        timestamp: ``time.monotonic()`` at receipt (0.0 without a clock).
        raw: The nine counts as received (``None`` for a sample built by hand); not
            part of equality.
    """

    accel: Vector3
    gyro: Vector3
    mag: Vector3
    timestamp: float = 0.0
    raw: ImuCounts | None = field(default=None, compare=False, repr=False)

    @property
    def linear_acceleration(self) -> Vector3:
        """Acceleration in m/s² (SI, as ROS REP 103 expects), from `accel`."""
        g = STANDARD_GRAVITY
        return Vector3(self.accel.x * g, self.accel.y * g, self.accel.z * g)

    @property
    def angular_velocity(self) -> Vector3:
        """Angular rate in rad/s (SI), from `gyro`."""
        r = math.pi / 180
        return Vector3(self.gyro.x * r, self.gyro.y * r, self.gyro.z * r)

    def scaled(self, scale: ImuScale) -> ImuSample:
        """This sample with ``scale`` applied to its raw counts.

        Raises:
            ValueError: The sample has no raw counts (it was built by hand).
        """
        c = self.raw
        if c is None:
            raise ValueError("this ImuSample has no raw counts to scale")
        a, w = scale.accel, scale.gyro
        return ImuSample(
            Vector3(c.accel_x / a, c.accel_y / a, c.accel_z / a),
            Vector3(c.gyro_x / w, c.gyro_y / w, c.gyro_z / w),
            self.mag,
            self.timestamp,
            c,
        )


@fast_repr
@dataclass(frozen=True, slots=True)
class VelocityFeedback:
    """The 0x12 velocity feedback frame (m/s and rad/s)."""

    linear: float
    angular: float
    timestamp: float = 0.0


@fast_repr
@dataclass(frozen=True, slots=True)
class BatteryReading:
    """The 0x13 battery frame (V)."""

    voltage: float
    timestamp: float = 0.0


@fast_repr
@dataclass(frozen=True, slots=True)
class LogMessage:
    """The 0xF1 log frame: one line of text from the board's firmware."""

    text: str
    timestamp: float = 0.0


@fast_repr
@dataclass(frozen=True, slots=True)
class LedReply:
    """The 0x01 reply: the LED state after the request tagged ``request_id``."""

    request_id: int
    on: bool


@fast_repr
@dataclass(frozen=True, slots=True)
class BuzzerReply:
    """The 0x02 reply: the buzzer state after the request tagged ``request_id``."""

    request_id: int
    on: bool


@fast_repr
@dataclass(frozen=True, slots=True)
class LedCommand:
    """0x01 request: switch or read the LED; the reply carries ``request_id`` back."""

    action: SwitchAction
    request_id: int


@fast_repr
@dataclass(frozen=True, slots=True)
class BuzzerCommand:
    """0x02 request: switch or read the buzzer; the reply carries ``request_id`` back."""

    action: SwitchAction
    request_id: int


@fast_repr
@dataclass(frozen=True, slots=True)
class MotorPwmCommand:
    """0x21: raw PWM value for one motor."""

    motor: Motor
    pwm: int


@fast_repr
@dataclass(frozen=True, slots=True)
class VelocityCommand:
    """0x22: linear and angular velocity in thousandths (mm/s and mrad/s)."""

    linear_milli: int
    angular_milli: int


@fast_repr
@dataclass(frozen=True, slots=True)
class ServoCommand:
    """0x31: servo angle in tenths of a degree."""

    servo: Servo
    angle_tenths: int


#: Every message the board sends.
BoardMessage: TypeAlias = (
    ImuSample | VelocityFeedback | BatteryReading | LogMessage | LedReply | BuzzerReply
)
#: Every frame the host sends.
BoardCommand: TypeAlias = (
    LedCommand | BuzzerCommand | MotorPwmCommand | VelocityCommand | ServoCommand
)
