"""chassis_sdk: an asyncio client SDK for robot bases that speak binary serial protocols.

Two devices are supported:

* :class:`Chassis`, a four-wheel skid-steer chassis (protocol A, ``ED DE`` frames);
* :class:`Board`, a controller board with IMU, LED, buzzer, motors and servos
  (protocol B, ``FE CE`` / ``AB BC`` frames).

Example::

    import chassis_sdk
    from chassis_sdk import Chassis

    async def main() -> None:
        async with Chassis("/dev/ttyUSB0") as robot:
            print(await robot.get_chassis_info())
            await robot.set_velocity(0.3, 0.0)
            async for t in robot.telemetry():
                print(t.linear, t.voltage)

    chassis_sdk.run(main())  # asyncio.run, with SIGTERM/SIGHUP stopping the robot too

The sans-IO codecs live in :mod:`chassis_sdk.protocol`; the simulators in
:mod:`chassis_sdk.sim`.
"""

import logging as _logging

from ._device import ConnectionState, LinkStats
from ._dispatch import Subscription
from ._run import run
from ._watchdog import MotionLimits
from .board import Board
from .chassis import Chassis
from .diagnostics import Diagnosis
from .errors import (
    ChassisError,
    ConnectionLostError,
    NotConnectedError,
    PortOpenError,
    ProtocolError,
    RequestTimeoutError,
)
from .events import EventKind, RobotEvent
from .odometry import Odometry
from .protocol import (
    BatteryReading,
    ChassisInfo,
    ChassisStatus,
    DockingState,
    DriverError,
    DriverStatus,
    ImuSample,
    Motor,
    MotorStatus,
    PowerTelemetry,
    Servo,
    Telemetry,
    Vector3,
    VelocityFeedback,
    WheelCurrents,
    WheelDriver,
    WheelSpeeds,
)

__version__ = "0.1.0"

# A library leaves logging to the application: without its own configuration, nothing
# from chassis_sdk reaches stderr (configure "chassis_sdk" to see link events).
_logging.getLogger("chassis_sdk").addHandler(_logging.NullHandler())

__all__ = [
    "BatteryReading",
    "Board",
    "Chassis",
    "ChassisError",
    "ChassisInfo",
    "ChassisStatus",
    "ConnectionLostError",
    "ConnectionState",
    "Diagnosis",
    "DockingState",
    "DriverError",
    "DriverStatus",
    "EventKind",
    "ImuSample",
    "LinkStats",
    "MotionLimits",
    "Motor",
    "MotorStatus",
    "NotConnectedError",
    "Odometry",
    "PortOpenError",
    "PowerTelemetry",
    "ProtocolError",
    "RequestTimeoutError",
    "RobotEvent",
    "Servo",
    "Subscription",
    "Telemetry",
    "Vector3",
    "VelocityFeedback",
    "WheelCurrents",
    "WheelDriver",
    "WheelSpeeds",
    "__version__",
    "run",
]
