"""The motion core: every command from every source passes one sans-IO arbiter
(`Arbiter`: sources, blocks, leases, priorities), and what it takes is held by the
`VelocityWatchdog` (resends, limits and ramps, the deadman, the one write period).

* `arbiter`: who may move the robot now (pure: no I/O, an injected clock);
* `watchdog`: the command in force, written at most once per `WRITE_PERIOD`;
* `drive`: `Motion`, a device's arbiter and watchdog together, and `MotionSource`, the
  handle each surface drives through;
* `goal`: goals as plans (drive a distance, turn, go to a pose), pure; `goals`: running
  one on a device as a source (`Goals`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .arbiter import (
        DEFAULT_PRIORITIES,
        WRITE_JITTER,
        WRITE_PERIOD,
        Arbiter,
        Refusal,
        RefusalReason,
        Source,
    )
    from .drive import Motion, MotionSource, frame_builder
    from .goal import MoveEnd, MoveResult
    from .goals import Goals
    from .watchdog import Axes, FrameBuilder, MotionCommand, MotionLimits, VelocityWatchdog

_LAZY = {
    "DEFAULT_PRIORITIES": ".arbiter",
    "WRITE_JITTER": ".arbiter",
    "WRITE_PERIOD": ".arbiter",
    "Arbiter": ".arbiter",
    "Refusal": ".arbiter",
    "RefusalReason": ".arbiter",
    "Source": ".arbiter",
    "Motion": ".drive",
    "MotionSource": ".drive",
    "frame_builder": ".drive",
    "MoveEnd": ".goal",
    "MoveResult": ".goal",
    "Goals": ".goals",
    "Axes": ".watchdog",
    "FrameBuilder": ".watchdog",
    "MotionCommand": ".watchdog",
    "MotionLimits": ".watchdog",
    "VelocityWatchdog": ".watchdog",
}

__all__ = [
    "DEFAULT_PRIORITIES",
    "WRITE_JITTER",
    "WRITE_PERIOD",
    "Arbiter",
    "Axes",
    "FrameBuilder",
    "Goals",
    "Motion",
    "MotionCommand",
    "MotionLimits",
    "MotionSource",
    "MoveEnd",
    "MoveResult",
    "Refusal",
    "RefusalReason",
    "Source",
    "VelocityWatchdog",
    "frame_builder",
]

__getattr__, __dir__ = _lazy(__name__, _LAZY, globals())
