"""The chassis's entry in the device registry: its codec and examples are imported;
the device class and the firmware model are named, and loaded on first use."""

from __future__ import annotations

from .. import Codec, DeviceProfile, Remote
from .messages import (
    ChassisInfo,
    ChassisStatus,
    Command,
    CommandId,
    DockingState,
    DriveVelocity,
    DriveWheels,
    FirmwareVersion,
    HardwareVersion,
    PowerTelemetry,
    ShipDate,
    Telemetry,
    WheelCurrents,
    WheelSpeeds,
)
from .protocol import ChassisCommandDecoder, ChassisDecoder

__all__ = ["PROFILE"]


def _h(text: str) -> bytes:
    return bytes.fromhex(text)


#: The vendor document's examples (with the errata's corrections) and simulator frames.
EXAMPLES = (
    (_h("ED DE 00 00 8A 0D 18 01 02 7D 02 BD BC"), ShipDate(2024, 1, 2)),
    (
        _h(
            "ED DE 00 00 88 22 5A 48 57 4C 2D 62 72 75 73 68 2D 6D 6F 74 6F 72 2D 63 68 61 73 "
            "73 69 73 84 0B BD BC"
        ),
        HardwareVersion("ZHWL-brush-motor-chassis"),
    ),
    # The document's 0x89 example: its length byte is wrong (0x12 for 20 bytes).
    (
        _h("ED DE 00 00 89 12 D5 02 F4 01 AA 00 1E 00 E8 03 E5 05 BD BC"),
        ChassisInfo(0.725, 0.5, 0.17, 30, 1000),
    ),
    (_h("ED DE 08 00 87 0C 02 01 69 02 BD BC"), FirmwareVersion(258)),
    (
        _h("ED DE 05 00 81 1C 00 01 08 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 76 02 BD BC"),
        Telemetry(
            25.6,
            ChassisStatus.REMOTE_OFFLINE,
            DockingState.SEARCHING,
            0.0,
            0.0,
            WheelSpeeds(0.0, 0.0, 0.0, 0.0),
            5,
            0.0,
        ),
    ),
    (
        _h("ED DE 06 00 B1 16 03 00 03 00 03 00 03 00 00 01 00 01 A6 02 BD BC"),
        PowerTelemetry(WheelCurrents(0.3, 0.3, 0.3, 0.3), 25.6, 25.6, 6, 0.0),
    ),
)
COMMAND_EXAMPLES = (
    (_h("ED DE 01 00 01 0C 01 00 DA 01 BD BC"), Command(CommandId.TELEMETRY, 1)),
    (_h("ED DE 00 00 02 12 00 00 C8 00 00 00 00 00 A7 02 BD BC"), DriveVelocity(200, 0.0)),
    (_h("ED DE 00 00 02 12 01 00 C8 00 C1 00 00 00 69 03 BD BC"), DriveWheels(200, 193)),
    (_h("ED DE 00 00 05 0C 04 00 E0 01 BD BC"), Command(CommandId.CLEAR_FAULTS, 4)),
    (_h("ED DE 00 00 B0 0C 01 00 88 02 BD BC"), Command(CommandId.DRIVER_STATUS, 1)),
)

PROFILE = DeviceProfile(
    name="chassis",
    summary="four-wheel skid-steer chassis (protocol A, ED DE frames)",
    recognised_by="0x81 chassis telemetry",
    device="chassis_sdk.devices.chassis.device:Chassis",
    firmware="chassis_sdk.devices.chassis.firmware:ChassisFirmware",
    codec=Codec(
        decoder=ChassisDecoder,
        command_decoder=ChassisCommandDecoder,
        examples=EXAMPLES,
        command_examples=COMMAND_EXAMPLES,
        max_buffered=256,
    ),
    remote=Remote(
        streams=("telemetry", "power", "odometry"),
        requests=(
            "get_firmware_version",
            "get_hardware_version",
            "get_chassis_info",
            "get_ship_date",
            "get_driver_status",
            "diagnose",
        ),
        identity=(
            "get_firmware_version",
            "get_hardware_version",
            "get_chassis_info",
            "get_ship_date",
        ),
        features={"drive": "skid-steer", "wheels": 4, "estop": True, "docking": True},
    ),
)
