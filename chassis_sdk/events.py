"""Robot events: edges decoded from what the device reports, as typed values.

A status word is a level ("the bumper is pressed"); an application usually wants the
edge ("the bumper was just hit"). :class:`StatusEdges` turns successive 0x81 status
words and docking states into :class:`RobotEvent` values, :class:`BatteryMonitor` does
the same for a voltage against a threshold (with hysteresis, so a sagging battery does
not chatter), and the device adds the link's own edges (stale, lost, restored). Every
edge is reported once; a level that holds produces nothing more.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from .protocol._scale import check_real
from .protocol.chassis import ChassisStatus, DockingState

__all__ = ["BatteryMonitor", "EventKind", "RobotEvent", "StatusEdges"]


class EventKind(enum.Enum):
    """What happened. ``source`` on the event says which one (see each member)."""

    ESTOP_ENGAGED = "estop_engaged"  #: source: "hardware", "remote" or "software"
    ESTOP_RELEASED = "estop_released"  #: source: "hardware", "remote" or "software"
    BUMPER_HIT = "bumper_hit"  #: source: "front" or "rear"
    BUMPER_CLEARED = "bumper_cleared"  #: source: "front" or "rear"
    DRIVER_OFFLINE = "driver_offline"  #: source: "front" or "rear" driver board
    DRIVER_ONLINE = "driver_online"  #: source: "front" or "rear" driver board
    DRIVER_ERROR = "driver_error"  #: source: the wheel, e.g. "front_left"
    DRIVER_ERROR_CLEARED = "driver_error_cleared"  #: source: the wheel
    DOCKING_CHANGED = "docking_changed"  #: ``docking`` holds the new state
    BATTERY_LOW = "battery_low"  #: ``voltage`` fell below the threshold
    BATTERY_OK = "battery_ok"  #: ``voltage`` rose back above threshold + hysteresis
    LINK_STALE = "link_stale"  #: no valid frame for ``link_timeout``
    LINK_LOST = "link_lost"  #: the port dropped
    LINK_RESTORED = "link_restored"  #: frames (or the port) are back


@dataclass(frozen=True, slots=True)
class RobotEvent:
    """One edge.

    Attributes:
        kind: What happened.
        source: Which e-stop, bumper, driver or wheel; empty when there is one only.
        timestamp: ``time.monotonic()`` of the frame (or state change) that showed it.
        docking: The new docking state, for ``DOCKING_CHANGED``.
        voltage: The battery voltage, for ``BATTERY_LOW`` and ``BATTERY_OK``.
    """

    kind: EventKind
    source: str = ""
    timestamp: float = 0.0
    docking: DockingState | None = None
    voltage: float | None = None

    def __str__(self) -> str:
        text = self.kind.value.replace("_", " ")
        if self.source:
            text += f" ({self.source})"
        if self.docking is not None:
            text += f": {self.docking.name}"
        if self.voltage is not None:
            text += f": {self.voltage:.1f} V"
        return text


S = ChassisStatus
E = EventKind
#: status bit -> (event when it sets, event when it clears, source)
_EDGES: tuple[tuple[ChassisStatus, EventKind, EventKind, str], ...] = (
    (S.HARDWARE_ESTOP, E.ESTOP_ENGAGED, E.ESTOP_RELEASED, "hardware"),
    (S.REMOTE_ESTOP, E.ESTOP_ENGAGED, E.ESTOP_RELEASED, "remote"),
    (S.SOFTWARE_ESTOP, E.ESTOP_ENGAGED, E.ESTOP_RELEASED, "software"),
    (S.FRONT_BUMPER, E.BUMPER_HIT, E.BUMPER_CLEARED, "front"),
    (S.REAR_BUMPER, E.BUMPER_HIT, E.BUMPER_CLEARED, "rear"),
    (S.FRONT_DRIVER_OFFLINE, E.DRIVER_OFFLINE, E.DRIVER_ONLINE, "front"),
    (S.REAR_DRIVER_OFFLINE, E.DRIVER_OFFLINE, E.DRIVER_ONLINE, "rear"),
    (S.FRONT_LEFT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "front_left"),
    (S.FRONT_RIGHT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "front_right"),
    (S.REAR_LEFT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "rear_left"),
    (S.REAR_RIGHT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "rear_right"),
)
_WATCHED = sum(int(bit) for bit, *_ in _EDGES)


class StatusEdges:
    """Turns successive (status, docking) levels into edge events.

    The first frame is compared with an all-clear status, so a fault present at
    connect time is reported; the docking state is reported on changes only.
    """

    def __init__(self) -> None:
        self._bits = 0  # plain int: IntFlag arithmetic costs a microsecond per operation
        self._docking: DockingState | None = None

    def update(self, status: ChassisStatus, docking: DockingState, ts: float) -> list[RobotEvent]:
        """The edges between the previous levels and these (usually none)."""
        bits = int(status)
        events: list[RobotEvent] = []
        changed = (bits ^ self._bits) & _WATCHED
        if changed:
            for bit, on, off, source in _EDGES:
                if bit & changed:
                    events.append(RobotEvent(on if bit & bits else off, source, ts))
            self._bits = bits
        if docking is not self._docking:
            if self._docking is not None:
                events.append(RobotEvent(E.DOCKING_CHANGED, "", ts, docking=docking))
            self._docking = docking
        return events


class BatteryMonitor:
    """``BATTERY_LOW`` below ``threshold``, ``BATTERY_OK`` at ``threshold + hysteresis``
    or above, each once per crossing.

    Args:
        threshold: Volts, or ``None`` to watch nothing.
        hysteresis: Volts above the threshold needed to call it OK again.
    """

    def __init__(self, threshold: float | None, hysteresis: float = 0.2) -> None:
        for name, value in (("battery_low", threshold), ("hysteresis", hysteresis)):
            if value is not None:
                check_real(value, name, low=0, unit="V")
        self.threshold = threshold
        self.hysteresis = hysteresis
        self.low = False

    def update(self, voltage: float, ts: float) -> RobotEvent | None:
        """The event this reading makes, if any."""
        if self.threshold is None:
            return None
        if not self.low and voltage < self.threshold:
            self.low = True
            return RobotEvent(E.BATTERY_LOW, "", ts, voltage=voltage)
        if self.low and voltage >= self.threshold + self.hysteresis:
            self.low = False
            return RobotEvent(E.BATTERY_OK, "", ts, voltage=voltage)
        return None
