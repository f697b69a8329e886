"""The controller board's entry in the device registry: its codec and examples are
imported; the device class and the firmware model are named, and loaded on first use."""

from __future__ import annotations

from .. import Codec, DeviceProfile, Remote
from .messages import (
    BatteryReading,
    BuzzerCommand,
    BuzzerReply,
    ImuSample,
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
from .protocol import ACCEL_SCALE, GYRO_SCALE, BoardCommandDecoder, BoardDecoder

__all__ = ["PROFILE"]


def _h(text: str) -> bytes:
    return bytes.fromhex(text)


#: Frames of every type the board sends, from the simulator's encoder.
EXAMPLES = (
    (
        _h("FE CE 11 13 01 00 FF FF A3 00 00 00 FF FF 00 00 2C 01 00 00 5C FE 4B"),
        ImuSample(
            Vector3(1 / ACCEL_SCALE, -1 / ACCEL_SCALE, 163 / ACCEL_SCALE),
            Vector3(0.0, -1 / GYRO_SCALE, 0.0),
            Vector3(300.0, 0.0, -420.0),
            0.0,
        ),
    ),
    (_h("FE CE 12 05 FA 00 0C FE 1B"), VelocityFeedback(0.25, -0.5, 0.0)),
    (_h("FE CE 13 03 CE 04 E8"), BatteryReading(12.3, 0.0)),
    (_h("FE CE F1 08 62 6F 6F 74 20 6F 6B A7"), LogMessage("boot ok", 0.0)),
    (_h("FE CE 01 03 07 01 0C"), LedReply(7, True)),
    (_h("FE CE 02 03 09 00 0E"), BuzzerReply(9, False)),
)
COMMAND_EXAMPLES = (
    (_h("AB BC 01 03 01 07 0C"), LedCommand(SwitchAction.ON, 7)),
    (_h("AB BC 02 03 02 09 10"), BuzzerCommand(SwitchAction.READ, 9)),
    (_h("AB BC 21 04 03 64 00 8C"), MotorPwmCommand(Motor.FRONT_LEFT, 100)),
    (_h("AB BC 22 05 C8 00 00 00 EF"), VelocityCommand(200, 0)),
    (_h("AB BC 31 04 01 C2 01 F9"), ServoCommand(Servo.FIRST, 450)),
)

PROFILE = DeviceProfile(
    name="board",
    summary="controller board with IMU, LED, buzzer, motors and servos (protocol B, FE CE)",
    recognised_by="0x11 board IMU samples",
    device="chassis_sdk.devices.board.device:Board",
    firmware="chassis_sdk.devices.board.firmware:BoardFirmware",
    codec=Codec(
        decoder=BoardDecoder,
        command_decoder=BoardCommandDecoder,
        examples=EXAMPLES,
        command_examples=COMMAND_EXAMPLES,
        # Protocol B holds up to three bytes past a frame whose end could start a head.
        max_buffered=262,
    ),
    remote=Remote(
        streams=("imu", "velocity", "battery", "odometry"),
        requests=("get_led", "get_buzzer", "diagnose"),
        features={"imu": True, "led": True, "buzzer": True, "motors": 4, "servos": 2},
    ),
)
