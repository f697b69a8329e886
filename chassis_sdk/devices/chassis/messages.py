"""Protocol A (the chassis): the typed messages and the enums of their fields.

Frozen, slotted dataclasses (and ``NamedTuple``s where a value is a plain tuple of
numbers), in SI units; the wire format is `.protocol`'s business.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple, TypeAlias

from ...core.construct import fast_repr
from ...core.enums import NamedEnum, NamedFlag

__all__ = [
    "ChassisInfo",
    "ChassisMessage",
    "ChassisStatus",
    "Command",
    "CommandId",
    "DockingState",
    "DriveVelocity",
    "DriveWheels",
    "DriverError",
    "DriverStatus",
    "FaultClear",
    "FirmwareVersion",
    "HardwareVersion",
    "HostCommand",
    "MotorStatus",
    "PowerTelemetry",
    "ReplyId",
    "ShipDate",
    "Telemetry",
    "WheelCurrents",
    "WheelDriver",
    "WheelSpeeds",
]


class CommandId(IntEnum):
    """Frame ids the host sends to the chassis."""

    TELEMETRY = 0x01  #: switch the 50 Hz 0x81 telemetry on or off
    DRIVE = 0x02  #: velocity command, linear mode (0) or wheel mode (1)
    EMERGENCY_STOP = 0x03  #: software emergency stop (1) or release (0)
    CLEAR_FAULTS = 0x05  #: clear driver and bumper faults (bit mask)
    DOCKING = 0x06  #: start (1) or stop (0) automatic docking
    FIRMWARE_VERSION = 0x07  #: read the firmware version; reply 0x87
    HARDWARE_VERSION = 0x08  #: read the hardware version string; reply 0x88
    CHASSIS_INFO = 0x09  #: read the geometry; reply 0x89
    SHIP_DATE = 0x0A  #: read the ship date; reply 0x8A
    DRIVER_STATUS = 0xB0  #: read the motor-driver status; reply 0xB0
    POWER_TELEMETRY = 0xB1  #: switch the 20 Hz 0xB1 current/voltage upload on or off


class ReplyId(IntEnum):
    """Frame ids the chassis sends to the host."""

    TELEMETRY = 0x81  #: 50 Hz telemetry (28 bytes)
    DRIVER_STATUS = 0xB0  #: motor-driver status (50 bytes), reply to 0xB0
    POWER = 0xB1  #: 20 Hz driver currents and voltages (22 bytes)
    FIRMWARE_VERSION = 0x87  #: firmware version (12 bytes)
    HARDWARE_VERSION = 0x88  #: hardware version, ASCII text (10 + N bytes)
    CHASSIS_INFO = 0x89  #: geometry (20 bytes)
    SHIP_DATE = 0x8A  #: ship date (13 bytes)


class ChassisStatus(NamedFlag):
    """Status bits of the 0x81 telemetry frame."""

    HARDWARE_ESTOP = 1 << 0  #: the hardware emergency-stop button is pressed
    REMOTE_ESTOP = 1 << 1  #: the remote control's emergency stop is active
    SOFTWARE_ESTOP = 1 << 2  #: the host's software emergency stop (0x03) is active
    REMOTE_OFFLINE = 1 << 3  #: the remote control is off or out of range
    FRONT_DRIVER_OFFLINE = 1 << 4  #: the front motor driver does not answer
    REAR_DRIVER_OFFLINE = 1 << 5  #: the rear motor driver does not answer
    FRONT_LEFT_DRIVER_ERROR = 1 << 6  #: the front-left driver reports an error
    FRONT_RIGHT_DRIVER_ERROR = 1 << 7  #: the front-right driver reports an error
    REAR_LEFT_DRIVER_ERROR = 1 << 8  #: the rear-left driver reports an error
    REAR_RIGHT_DRIVER_ERROR = 1 << 9  #: the rear-right driver reports an error
    FRONT_BUMPER = 1 << 10  #: the front bumper is triggered
    REAR_BUMPER = 1 << 11  #: the rear bumper is triggered
    DOCKING_ENABLED = 1 << 12  #: automatic docking is switched on

    ESTOP = HARDWARE_ESTOP | REMOTE_ESTOP | SOFTWARE_ESTOP  #: any emergency stop
    DRIVER_FAULT = (
        FRONT_DRIVER_OFFLINE
        | REAR_DRIVER_OFFLINE
        | FRONT_LEFT_DRIVER_ERROR
        | FRONT_RIGHT_DRIVER_ERROR
        | REAR_LEFT_DRIVER_ERROR
        | REAR_RIGHT_DRIVER_ERROR
    )  #: any driver offline or in error
    BUMPER = FRONT_BUMPER | REAR_BUMPER  #: either bumper


class DockingState(NamedEnum):
    """Docking state of the 0x81 telemetry frame.

    A value the document does not list decodes to a pseudo-member named
    ``UNKNOWN_<value>`` instead of failing, so new firmware cannot break a loop.
    """

    SEARCHING = 0  #: searching for the dock's centre line
    CENTER_FOUND = 1  #: centre line found, approaching
    SIGNAL_LOST = 2  #: the dock's signal was lost
    CONTACT = 3  #: the charging contacts touch
    DOCKED = 4  #: docked and charging
    ERROR = 5  #: docking failed
    TIMEOUT = 6  #: docking timed out
    EXITED = 7  #: left the charging state

    @classmethod
    def _missing_(cls, value: object) -> DockingState | None:
        if isinstance(value, int) and 0 <= value <= 0xFFFF:
            member = int.__new__(cls, value)
            member._name_ = f"UNKNOWN_{value}"
            member._value_ = value
            return member
        return None


class DriverError(NamedFlag):
    """Error bits of one motor driver (0xB0 reply)."""

    UNDER_VOLTAGE = 1 << 0  #: battery under-voltage
    POSITION_ERROR = 1 << 1  #: position error
    HALL_SENSOR = 1 << 2  #: hall sensor error
    OVER_CURRENT = 1 << 3  #: over-current
    OVERLOAD = 1 << 4  #: overload
    EEPROM = 1 << 5  #: EEPROM fault
    IGBT = 1 << 6  #: IGBT (power stage) fault
    DRIVER_OVER_TEMPERATURE = 1 << 7  #: driver over-temperature
    MOTOR_DEFECT = 1 << 8  #: motor defect
    SUPPLY_OUT_OF_TOLERANCE = 1 << 9  #: supply voltage out of tolerance
    SPEED_OUT_OF_TOLERANCE = 1 << 10  #: speed out of tolerance
    MOTOR_OVER_TEMPERATURE = 1 << 11  #: motor over-temperature
    SUPPLY_OVER_VOLTAGE = 1 << 12  #: supply over-voltage
    RUNAWAY = 1 << 13  #: runaway (speed not under control)
    #: driver over-temperature, second bit (the document names bits 7 and 14 alike)
    DRIVER_OVER_TEMPERATURE_2 = 1 << 14


class MotorStatus(NamedFlag):
    """Motor status bits of one motor driver (0xB0 reply)."""

    SERVO_STARTED = 1 << 0  #: servo enabled
    SERVO_RUNNING = 1 << 1  #: servo running
    ZERO_SPEED = 1 << 2  #: running at zero speed
    TARGET_SPEED_REACHED = 1 << 3  #: target speed reached
    TARGET_POSITION_REACHED = 1 << 4  #: target position reached
    TORQUE_LIMITING = 1 << 5  #: torque limit active
    WARNING = 1 << 6  #: warning
    BRAKE_OUTPUT = 1 << 7  #: brake output active
    HOMING_DONE = 1 << 8  #: homing complete
    OVERLOAD_THRESHOLD = 1 << 9  #: overload threshold exceeded
    ERROR_WARNING = 1 << 10  #: error warning
    COMMAND_COMPLETE = 1 << 11  #: command complete
    REVERSE_STALL = 1 << 12  #: stalled in reverse
    FORWARD_STALL = 1 << 13  #: stalled forwards


class FaultClear(NamedFlag):
    """What a 0x05 clear-faults frame clears."""

    DRIVER = 1 << 0  #: motor-driver faults
    FRONT_BUMPER = 1 << 1  #: front bumper latch
    REAR_BUMPER = 1 << 2  #: rear bumper latch


@fast_repr
class WheelSpeeds(NamedTuple):
    """A value per wheel (m/s for speeds)."""

    front_left: float
    front_right: float
    rear_left: float
    rear_right: float


@fast_repr
class WheelCurrents(NamedTuple):
    """Motor current per wheel, in amperes."""

    front_left: float
    front_right: float
    rear_left: float
    rear_right: float


@fast_repr
@dataclass(frozen=True, slots=True)
class Telemetry:
    """The 50 Hz 0x81 telemetry frame, in SI units.

    Attributes:
        voltage: Battery voltage (V).
        status: Status bits.
        docking: Docking state.
        linear: Measured linear velocity (m/s, forward positive).
        angular: Measured angular velocity (rad/s, counter-clockwise positive).
        wheels: Measured wheel speeds (m/s).
        seq: The device's frame sequence number (wraps at 65536).
        timestamp: ``time.monotonic()`` when the frame was received (0.0 when decoded
            without a clock).
    """

    voltage: float
    status: ChassisStatus
    docking: DockingState
    linear: float
    angular: float
    wheels: WheelSpeeds
    seq: int = 0
    timestamp: float = 0.0

    @property
    def emergency_stopped(self) -> bool:
        """True if any emergency stop (hardware, remote or software) is active."""
        return bool(self.status & ChassisStatus.ESTOP)


@fast_repr
@dataclass(frozen=True, slots=True)
class WheelDriver:
    """Status of one wheel's motor driver.

    Attributes:
        errors: Driver error bits (empty when healthy).
        motor: Motor status bits.
        current: Motor current (A, signed).
        peak_current: Peak current (A).
    """

    errors: DriverError
    motor: MotorStatus
    current: float
    peak_current: float


@fast_repr
@dataclass(frozen=True, slots=True)
class DriverStatus:
    """The 0xB0 motor-driver status reply.

    Attributes:
        front_left: Front-left wheel driver.
        front_right: Front-right wheel driver.
        rear_left: Rear-left wheel driver.
        rear_right: Rear-right wheel driver.
        temperature_front: Front driver temperature (°C).
        temperature_rear: Rear driver temperature (°C).
        voltage_front: Front driver supply voltage (V).
        voltage_rear: Rear driver supply voltage (V).
    """

    front_left: WheelDriver
    front_right: WheelDriver
    rear_left: WheelDriver
    rear_right: WheelDriver
    temperature_front: float
    temperature_rear: float
    voltage_front: float
    voltage_rear: float

    @property
    def wheels(self) -> tuple[WheelDriver, WheelDriver, WheelDriver, WheelDriver]:
        """The four drivers in wire order (FL, FR, RL, RR)."""
        return (self.front_left, self.front_right, self.rear_left, self.rear_right)


@fast_repr
@dataclass(frozen=True, slots=True)
class PowerTelemetry:
    """The 20 Hz 0xB1 driver current and voltage frame.

    Attributes:
        currents: Motor current per wheel (A).
        voltage_front: Front driver supply voltage (V).
        voltage_rear: Rear driver supply voltage (V).
        seq: The device's frame sequence number.
        timestamp: ``time.monotonic()`` at receipt (0.0 without a clock).
    """

    currents: WheelCurrents
    voltage_front: float
    voltage_rear: float
    seq: int = 0
    timestamp: float = 0.0


@fast_repr
@dataclass(frozen=True, slots=True)
class FirmwareVersion:
    """The 0x87 reply: the firmware version number."""

    version: int


@fast_repr
@dataclass(frozen=True, slots=True)
class HardwareVersion:
    """The 0x88 reply: the hardware version string."""

    text: str


@fast_repr
@dataclass(frozen=True, slots=True)
class ChassisInfo:
    """The 0x89 reply: the chassis geometry, lengths in metres.

    Attributes:
        track_width: Distance between left and right wheels (m).
        wheelbase: Distance between front and rear axles (m).
        wheel_diameter: Wheel diameter (m).
        gear_ratio: Motor-to-wheel reduction ratio.
        encoder_resolution: Encoder lines per motor revolution.
    """

    track_width: float
    wheelbase: float
    wheel_diameter: float
    gear_ratio: int
    encoder_resolution: int


@fast_repr
@dataclass(frozen=True, slots=True)
class ShipDate:
    """The 0x8A reply, as sent: year (full, e.g. 2024), month and day."""

    year: int
    month: int
    day: int

    def to_date(self) -> datetime.date:
        """Return the date. Raises ``ValueError`` if the device sent an impossible one."""
        return datetime.date(self.year, self.month, self.day)


@fast_repr
@dataclass(frozen=True, slots=True)
class Command:
    """A 12-byte host command whose data is one uint16 (every id but 0x02)."""

    id: CommandId
    value: int = 0


@fast_repr
@dataclass(frozen=True, slots=True)
class DriveVelocity:
    """0x02 mode 0: drive with a linear (mm/s) and an angular (rad/s, float32) velocity."""

    linear_mm: int
    angular: float


@fast_repr
@dataclass(frozen=True, slots=True)
class DriveWheels:
    """0x02 mode 1: drive with left and right side speeds (mm/s)."""

    left_mm: int
    right_mm: int


#: Every message the chassis sends.
ChassisMessage: TypeAlias = (
    Telemetry
    | DriverStatus
    | PowerTelemetry
    | FirmwareVersion
    | HardwareVersion
    | ChassisInfo
    | ShipDate
)
#: Every frame the host sends.
HostCommand: TypeAlias = Command | DriveVelocity | DriveWheels
