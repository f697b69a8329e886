"""Robot events (kept at this path for code written against it).

The mechanism and the shared vocabulary live in :mod:`chassis_sdk.core.events`; the
chassis's table of status edges in :mod:`chassis_sdk.devices.chassis.health`.
"""

from .core.events import BatteryMonitor, EventKind, RobotEvent
from .devices.chassis.health import StatusEdges

__all__ = ["BatteryMonitor", "EventKind", "RobotEvent", "StatusEdges"]
