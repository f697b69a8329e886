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
:mod:`chassis_sdk.sim`. Underneath, :mod:`chassis_sdk.core` knows no protocol and each
device is a package in :mod:`chassis_sdk.devices`, found through a registry
(:func:`chassis_sdk.devices.profiles`) that installed packages can extend.
"""

import logging as _logging

from .core.device import ConnectionState, LinkStats
from .core.diagnosis import Diagnosis
from .core.dispatch import Subscription
from .core.events import EventKind, RobotEvent
from .core.odometry import Odometry
from .core.run import run
from .core.watchdog import MotionLimits
from .devices.board import Board
from .devices.chassis import Chassis
from .errors import (
    ChassisError,
    ConnectionLostError,
    NotConnectedError,
    PortOpenError,
    ProtocolError,
    RequestTimeoutError,
)
from .protocol import (
    BatteryReading,
    ChassisInfo,
    ChassisStatus,
    DockingState,
    DriverError,
    DriverStatus,
    ImuSample,
    ImuScale,
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
    "ImuScale",
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
