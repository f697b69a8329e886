"""Sans-IO codecs for both protocols: decoders, encoders and the message types.

Nothing in this package does I/O or reads a clock, so it can decode captured byte logs,
run inside a simulator, or be tested with plain bytes::

    from chassis_sdk.protocol import ChassisDecoder

    decoder = ChassisDecoder()
    for chunk in chunks:
        for message in decoder.feed(chunk):
            print(message)
    print(decoder.stats)

The codecs live with their devices (`chassis_sdk.devices`); this package gathers
them under the paths code was written against (``chassis_sdk.devices.chassis.protocol`` and
``.board`` included).
"""

from ..core.framing import DecoderStats, FrameDecoder
from ..devices.board.messages import (
    BatteryReading,
    BoardCommand,
    BoardMessage,
    BoardType,
    BuzzerCommand,
    BuzzerReply,
    ImuCounts,
    ImuSample,
    ImuScale,
    LedCommand,
    LedReply,
    LogMessage,
    Motor,
    MotorPwmCommand,
    Servo,
    ServoCommand,
    SwitchAction,
    Vector3,
    VelocityCommand,
    VelocityFeedback,
)
from ..devices.board.protocol import BoardCommandDecoder, BoardDecoder, BoardEncoder
from ..devices.chassis.messages import (
    ChassisInfo,
    ChassisMessage,
    ChassisStatus,
    Command,
    CommandId,
    DockingState,
    DriverError,
    DriverStatus,
    DriveVelocity,
    DriveWheels,
    FaultClear,
    FirmwareVersion,
    HardwareVersion,
    HostCommand,
    MotorStatus,
    PowerTelemetry,
    ReplyId,
    ShipDate,
    Telemetry,
    WheelCurrents,
    WheelDriver,
    WheelSpeeds,
)
from ..devices.chassis.protocol import ChassisCommandDecoder, ChassisDecoder, ChassisEncoder

__all__ = [
    "BatteryReading",
    "BoardCommand",
    "BoardCommandDecoder",
    "BoardDecoder",
    "BoardEncoder",
    "BoardMessage",
    "BoardType",
    "BuzzerCommand",
    "BuzzerReply",
    "ChassisCommandDecoder",
    "ChassisDecoder",
    "ChassisEncoder",
    "ChassisInfo",
    "ChassisMessage",
    "ChassisStatus",
    "Command",
    "CommandId",
    "DecoderStats",
    "DockingState",
    "DriveVelocity",
    "DriveWheels",
    "DriverError",
    "DriverStatus",
    "FaultClear",
    "FirmwareVersion",
    "FrameDecoder",
    "HardwareVersion",
    "HostCommand",
    "ImuCounts",
    "ImuSample",
    "ImuScale",
    "LedCommand",
    "LedReply",
    "LogMessage",
    "Motor",
    "MotorPwmCommand",
    "MotorStatus",
    "PowerTelemetry",
    "ReplyId",
    "Servo",
    "ServoCommand",
    "ShipDate",
    "SwitchAction",
    "Telemetry",
    "Vector3",
    "VelocityCommand",
    "VelocityFeedback",
    "WheelCurrents",
    "WheelDriver",
    "WheelSpeeds",
]
