"""chassis_sdk: an asyncio client SDK for robot bases that speak binary serial protocols.

Two devices are supported:

* [`Chassis`][chassis_sdk.Chassis], a four-wheel skid-steer chassis (protocol A, ``ED DE`` frames);
* [`Board`][chassis_sdk.Board], a controller board with IMU, LED, buzzer, motors and servos
  (protocol B, ``FE CE`` / ``AB BC`` frames).

Example:
    ```python
    import chassis_sdk
    from chassis_sdk import Chassis

    async def main() -> None:
        async with Chassis("/dev/ttyUSB0") as robot:
            print(await robot.get_chassis_info())
            await robot.set_velocity(0.3, 0.0)
            async for t in robot.telemetry():
                print(t.linear, t.voltage)

    chassis_sdk.run(main())  # asyncio.run, with SIGTERM/SIGHUP stopping the robot too
    ```

The sans-IO codecs live in `chassis_sdk.protocol`; the simulators in
`chassis_sdk.sim`; recording in `chassis_sdk.recording`; the MQTT bridge and
the Foxglove server in `chassis_sdk.integrations`. Underneath,
`chassis_sdk.core` knows no protocol and each device is a package in
`chassis_sdk.devices`, found through a registry (`chassis_sdk.devices.profiles`)
that installed packages can extend.

Every name here is imported on first use (PEP 562): ``import chassis_sdk`` loads
nothing of the runtime, so ``chassis_sdk.protocol`` decodes captures without asyncio.
"""

from __future__ import annotations

import logging as _logging
from typing import TYPE_CHECKING

from ._lazy import lazy as _lazy
from ._version import __version__
from .errors import (
    ChassisError,
    ConnectionLostError,
    MotionBlockedError,
    MovePreemptedError,
    MoveTimeoutError,
    NotConnectedError,
    PortOpenError,
    ProtocolError,
    RequestTimeoutError,
)

if TYPE_CHECKING:
    from .core.battery import BatteryLevel, BatteryModel
    from .core.calibration import Calibration
    from .core.diagnosis import Diagnosis
    from .core.dispatch import Listener, ListenerStats, Subscription
    from .core.events import EventKind, RobotEvent
    from .core.geometry import Geometry
    from .core.motion import MotionLimits, MoveResult
    from .core.motion.safety import Geofence, Reflex, SafetyPolicy
    from .core.notifier import Notifier
    from .core.odometry import Odometry
    from .core.run import run
    from .core.stats import LinkStats
    from .core.supervisor import ConnectionState
    from .devices.board.device import Board
    from .devices.board.messages import (
        BatteryReading,
        ImuSample,
        ImuScale,
        Motor,
        Servo,
        Vector3,
        VelocityFeedback,
    )
    from .devices.chassis.device import Chassis
    from .devices.chassis.messages import (
        ChassisInfo,
        ChassisStatus,
        DockingState,
        DriverError,
        DriverStatus,
        MotorStatus,
        PowerTelemetry,
        Telemetry,
        WheelCurrents,
        WheelDriver,
        WheelSpeeds,
    )
    from .devices.config import Profile, ProfileError, load_profile
    from .devices.robot import open_robot

#: Where each lazily imported name lives.
_LAZY = {
    "ConnectionState": ".core.supervisor",
    "LinkStats": ".core.stats",
    "Diagnosis": ".core.diagnosis",
    "BatteryLevel": ".core.battery",
    "BatteryModel": ".core.battery",
    "Calibration": ".core.calibration",
    "Subscription": ".core.dispatch",
    "Listener": ".core.dispatch",
    "ListenerStats": ".core.dispatch",
    "Notifier": ".core.notifier",
    "EventKind": ".core.events",
    "RobotEvent": ".core.events",
    "Geometry": ".core.geometry",
    "Odometry": ".core.odometry",
    "run": ".core.run",
    "MotionLimits": ".core.motion",
    "MoveResult": ".core.motion",
    "Geofence": ".core.motion.safety",
    "Reflex": ".core.motion.safety",
    "SafetyPolicy": ".core.motion.safety",
    "Board": ".devices.board.device",
    "Profile": ".devices.config",
    "ProfileError": ".devices.config",
    "load_profile": ".devices.config",
    "open_robot": ".devices.robot",
    "Chassis": ".devices.chassis.device",
    "BatteryReading": ".devices.board.messages",
    "ImuSample": ".devices.board.messages",
    "ImuScale": ".devices.board.messages",
    "Motor": ".devices.board.messages",
    "Servo": ".devices.board.messages",
    "Vector3": ".devices.board.messages",
    "VelocityFeedback": ".devices.board.messages",
    "ChassisInfo": ".devices.chassis.messages",
    "ChassisStatus": ".devices.chassis.messages",
    "DockingState": ".devices.chassis.messages",
    "DriverError": ".devices.chassis.messages",
    "DriverStatus": ".devices.chassis.messages",
    "MotorStatus": ".devices.chassis.messages",
    "PowerTelemetry": ".devices.chassis.messages",
    "Telemetry": ".devices.chassis.messages",
    "WheelCurrents": ".devices.chassis.messages",
    "WheelDriver": ".devices.chassis.messages",
    "WheelSpeeds": ".devices.chassis.messages",
}

# A library leaves logging to the application: without its own configuration, nothing
# from chassis_sdk reaches stderr (configure "chassis_sdk" to see link events).
_logging.getLogger("chassis_sdk").addHandler(_logging.NullHandler())

__all__ = [
    "BatteryLevel",
    "BatteryModel",
    "BatteryReading",
    "Board",
    "Calibration",
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
    "Geofence",
    "Geometry",
    "ImuSample",
    "ImuScale",
    "LinkStats",
    "Listener",
    "ListenerStats",
    "MotionBlockedError",
    "MotionLimits",
    "Motor",
    "MotorStatus",
    "MovePreemptedError",
    "MoveResult",
    "MoveTimeoutError",
    "NotConnectedError",
    "Notifier",
    "Odometry",
    "PortOpenError",
    "PowerTelemetry",
    "Profile",
    "ProfileError",
    "ProtocolError",
    "Reflex",
    "RequestTimeoutError",
    "RobotEvent",
    "SafetyPolicy",
    "Servo",
    "Subscription",
    "Telemetry",
    "Vector3",
    "VelocityFeedback",
    "WheelCurrents",
    "WheelDriver",
    "WheelSpeeds",
    "__version__",
    "load_profile",
    "open_robot",
    "run",
]


__getattr__, __dir__ = _lazy(__name__, _LAZY, globals())
