"""The core: everything a device needs that knows no protocol.

Nothing here imports a device package. Modules, bottom up:

* :mod:`.validation`: the one check of numbers from a caller, and SI-to-wire scaling;
* :mod:`.framing`: the incremental frame scanner every codec builds on;
* :mod:`.construct`: fast construction of frozen message types (decoders' hot path);
* :mod:`.transport`: the link (one per port) and opening ports of every kind;
* :mod:`.dispatch`: streams with their latest value, and the table of requests;
* :mod:`.requests`: writing requests, retries, matching replies;
* :mod:`.supervisor`: lifetime, the close fence, reconnect, link health;
* :mod:`.watchdog`: the velocity watchdog, deadman and limits;
* :mod:`.odometry`, :mod:`.events`, :mod:`.diagnosis`, :mod:`.stats`: what a device
  reports, generically;
* :mod:`.device`: the :class:`Device` base (with the :mod:`.motion` and
  :mod:`.observation` facets) that a device subclasses;
* :mod:`.simulator`: serving a firmware model on a pty or TCP, with line faults;
* :mod:`.run`: ``chassis_sdk.run``, SIGTERM-safe ``asyncio.run``.
"""

from .device import Device
from .diagnosis import Diagnosis, Findings
from .dispatch import Broadcast, Subscription
from .events import EdgeDetector, EventKind, RobotEvent
from .framing import INVALID, NEED_DATA, DecoderStats, FrameDecoder
from .simulator import Firmware, LineFaults, SimulatorServer
from .stats import LinkStats
from .supervisor import ConnectionState
from .watchdog import FrameBuilder, MotionLimits

__all__ = [
    "INVALID",
    "NEED_DATA",
    "Broadcast",
    "ConnectionState",
    "DecoderStats",
    "Device",
    "Diagnosis",
    "EdgeDetector",
    "EventKind",
    "Findings",
    "Firmware",
    "FrameBuilder",
    "FrameDecoder",
    "LineFaults",
    "LinkStats",
    "MotionLimits",
    "RobotEvent",
    "SimulatorServer",
    "Subscription",
]
