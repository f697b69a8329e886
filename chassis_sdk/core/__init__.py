"""The core: everything a device needs that knows no protocol and no file format.

Nothing here imports a device, a recorder, an integration or the command line.
Modules, bottom up. The pure parts (no asyncio, no clock of their own):

* `.validation`: the one check of numbers from a caller, and SI-to-wire scaling;
* `.framing`: the incremental frame scanner every codec builds on;
* `.construct`: fast construction of frozen message types (decoders' hot path);
* `.enums`: enums and flags that print their names; `.plain`: messages as
  plain data (JSON, CSV);
* `.firmware`: the base of the sans-IO firmware models the simulators serve;
* `.writequeue`: the link's write discipline (velocity as state, the final zero);
* `.alarm`, `.backoff`: a wakeable sleep, and reconnect delays;
* `.battery`, `.charge`, `.pack`: the state of charge from voltage (and
  current), how every surface shows it, and the simulated pack;
* `.calibration`: the odometry's calibration factors.

The runtime:

* `.transport`: the link (one per port) and opening ports of every kind (the
  serial backend is chosen at the first open); `.ports`: listing serial ports;
* `.dispatch`: streams with their latest value, and the table of requests;
* `.requests`: writing requests, retries, matching replies;
* `.supervisor`: lifetime, the close fence, reconnect, link health;
* `.watchdog`: the velocity watchdog, deadman and limits; `.motion`: a
  device's motion commands over it;
* `.odometry`, `.events`, `.diagnosis`, `.stats`: what a device
  reports, generically; `.observation`: a device's streams and reports;
* `.session`, `.device`: the `Device` base that a device subclasses
  (its port side, and its robot side); `.notifier`: watching a device from outside;
* `.run`: ``chassis_sdk.run``, SIGTERM-safe ``asyncio.run``.

The names below are what a device package is written with (see "Adding a device");
each is imported on first use, so ``chassis_sdk.core.framing`` loads alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .device import Device
    from .diagnosis import Diagnosis, Findings
    from .dispatch import Broadcast, Listener, ListenerStats, Subscription
    from .events import EdgeDetector, EventKind, RobotEvent
    from .firmware import Firmware, FirmwareModel, next_slot
    from .framing import INVALID, NEED_DATA, DecoderStats, FrameDecoder, FrameTable
    from .geometry import Geometry
    from .motion import FrameBuilder, MotionLimits
    from .notifier import Notifier
    from .stats import LinkStats
    from .supervisor import ConnectionState

_LAZY = {
    "DecoderStats": ".framing",
    "FrameDecoder": ".framing",
    "FrameTable": ".framing",
    "INVALID": ".framing",
    "NEED_DATA": ".framing",
    "Device": ".device",
    "Diagnosis": ".diagnosis",
    "Findings": ".diagnosis",
    "Broadcast": ".dispatch",
    "Subscription": ".dispatch",
    "Listener": ".dispatch",
    "ListenerStats": ".dispatch",
    "EdgeDetector": ".events",
    "EventKind": ".events",
    "RobotEvent": ".events",
    "Geometry": ".geometry",
    "Firmware": ".firmware",
    "FirmwareModel": ".firmware",
    "next_slot": ".firmware",
    "LinkStats": ".stats",
    "Notifier": ".notifier",
    "ConnectionState": ".supervisor",
    "FrameBuilder": ".motion",
    "MotionLimits": ".motion",
}

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
    "FirmwareModel",
    "FrameBuilder",
    "FrameDecoder",
    "FrameTable",
    "Geometry",
    "LinkStats",
    "Listener",
    "ListenerStats",
    "MotionLimits",
    "Notifier",
    "RobotEvent",
    "Subscription",
    "next_slot",
]


__getattr__, __dir__ = _lazy(__name__, _LAZY, globals())
