"""Protocol B (the controller board): the typed messages and the enums of their fields.

Frozen, slotted dataclasses (and ``NamedTuple``s where a value is a plain tuple of
numbers), in SI units; the wire format is :mod:`.protocol`'s business.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple, TypeAlias

from ...core.enums import NamedEnum

__all__ = [
    "BatteryReading",
    "BoardCommand",
    "BoardMessage",
    "BoardType",
    "BuzzerCommand",
    "BuzzerReply",
    "ImuSample",
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


class Vector3(NamedTuple):
    """Three axes of one sensor."""

    x: float
    y: float
    z: float


@dataclass(frozen=True, slots=True)
class ImuSample:
    """The 0x11 IMU frame.

    Attributes:
        accel: Acceleration, raw / 164.0 (the vendor's scale; in g for a ±2 g part).
        gyro: Angular rate, raw / 16.4 (the vendor's scale; degrees per second).
        mag: Magnetic field, raw counts (the document gives no scale).
        timestamp: ``time.monotonic()`` at receipt (0.0 without a clock).
    """

    accel: Vector3
    gyro: Vector3
    mag: Vector3
    timestamp: float = 0.0


@dataclass(frozen=True, slots=True)
class VelocityFeedback:
    """The 0x12 velocity feedback frame (m/s and rad/s)."""

    linear: float
    angular: float
    timestamp: float = 0.0


@dataclass(frozen=True, slots=True)
class BatteryReading:
    """The 0x13 battery frame (V)."""

    voltage: float
    timestamp: float = 0.0


@dataclass(frozen=True, slots=True)
class LogMessage:
    """The 0xF1 log frame: one line of text from the board's firmware."""

    text: str
    timestamp: float = 0.0


@dataclass(frozen=True, slots=True)
class LedReply:
    """The 0x01 reply: the LED state after the request tagged ``request_id``."""

    request_id: int
    on: bool


@dataclass(frozen=True, slots=True)
class BuzzerReply:
    """The 0x02 reply: the buzzer state after the request tagged ``request_id``."""

    request_id: int
    on: bool


@dataclass(frozen=True, slots=True)
class LedCommand:
    """0x01 request: switch or read the LED; the reply carries ``request_id`` back."""

    action: SwitchAction
    request_id: int


@dataclass(frozen=True, slots=True)
class BuzzerCommand:
    """0x02 request: switch or read the buzzer; the reply carries ``request_id`` back."""

    action: SwitchAction
    request_id: int


@dataclass(frozen=True, slots=True)
class MotorPwmCommand:
    """0x21: raw PWM value for one motor."""

    motor: Motor
    pwm: int


@dataclass(frozen=True, slots=True)
class VelocityCommand:
    """0x22: linear and angular velocity in thousandths (mm/s and mrad/s)."""

    linear_milli: int
    angular_milli: int


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
