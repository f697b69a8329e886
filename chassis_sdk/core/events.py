"""Robot events: edges decoded from what the device reports, as typed values.

A status word is a level ("the bumper is pressed"); an application usually wants the
edge ("the bumper was just hit"). `EdgeDetector` turns successive status words
into `RobotEvent` values from a table that the device supplies (which bit means
what), and reports a device state (docking, say) when it changes;
`BatteryMonitor` does the same for a voltage against a threshold (with
hysteresis, so a sagging battery does not chatter; a device given a ``BatteryModel``
reports the same kinds, and ``BATTERY_CRITICAL``, from the state of charge instead), and
the device base adds the link's
own edges (stale, lost, restored). Every edge is reported once; a level that holds
produces nothing more.

`EventKind` is the shared vocabulary of a mobile base (e-stops, bumpers, drivers,
docking, battery, link); which of a device's status bits means which kind, and from
which ``source``, is the device's own table.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from .validation import check_real

__all__ = ["BatteryMonitor", "Edge", "EdgeDetector", "EventKind", "Measure", "RobotEvent"]


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
    DOCKING_CHANGED = "docking_changed"  #: ``state`` (alias ``docking``) holds the new state
    #: ``voltage`` fell below ``battery_low``, or (``percentage`` set) the state of
    #: charge below the ``BatteryModel``'s ``low``
    BATTERY_LOW = "battery_low"
    #: ``voltage`` (or ``percentage``) rose back above threshold + hysteresis
    BATTERY_OK = "battery_ok"
    #: ``percentage`` fell below the ``BatteryModel``'s ``critical`` (after ``BATTERY_LOW``)
    BATTERY_CRITICAL = "battery_critical"
    LINK_STALE = "link_stale"  #: no valid frame for ``link_timeout``
    LINK_LOST = "link_lost"  #: the port dropped
    LINK_RESTORED = "link_restored"  #: frames (or the port) are back
    #: a reflex acted: source: the hazard (``"front_bumper"``, ``"stall"``, ``"tilt"``,
    #: ``"geofence"``, ``"battery"``, ``"link"``); ``action`` what it did; ``values``
    #: what was measured
    REFLEX = "reflex"
    #: the hazard of a reflex is over (a ``slow`` cap or a lasting block ends)
    REFLEX_ENDED = "reflex_ended"
    #: the safety policy ignores a hazard (``allow_unsafe``): source: the hazard
    SAFETY_OVERRIDDEN = "safety_overridden"


class Measure(NamedTuple):
    """One value a reflex measured (``Measure("tilt", 31.2)``; JSON: an object)."""

    name: str
    value: float


@dataclass(frozen=True, slots=True)
class RobotEvent:
    """One edge.

    Attributes:
        kind: What happened.
        source: Which e-stop, bumper, driver or wheel; empty when there is one only.
        timestamp: ``time.monotonic()`` of the frame (or state change) that showed it.
        state: The new state, for a state change such as ``DOCKING_CHANGED``.
        voltage: The battery voltage, for ``BATTERY_LOW``, ``BATTERY_OK`` and
            ``BATTERY_CRITICAL``.
        percentage: The state of charge (percent), for the events of a
            ``BatteryModel`` (``None`` for those of ``battery_low``, a voltage).
        action: What a reflex did (``"stop"``, ``"back_off"``, ``"slow"``,
            ``"ignore"``), for ``REFLEX``, ``REFLEX_ENDED`` and ``SAFETY_OVERRIDDEN``.
        values: What a reflex measured (``(Measure("tilt", 31.2),)``).
    """

    kind: EventKind
    source: str = ""
    timestamp: float = 0.0
    state: enum.Enum | None = None
    voltage: float | None = None
    percentage: float | None = None
    action: str | None = None
    values: tuple[Measure, ...] = ()

    @property
    def docking(self) -> enum.Enum | None:
        """The new docking state of ``DOCKING_CHANGED`` (the same as `state`)."""
        return self.state

    def __str__(self) -> str:
        text = str(self.kind.value).replace("_", " ")
        if self.source:
            text += f" ({self.source})"
        if self.state is not None:
            text += f": {self.state.name}"
        if self.voltage is not None:
            text += f": {self.voltage:.1f} V"
        if self.percentage is not None:
            text += f", {self.percentage:.0f} %"
        if self.action is not None:
            text += f" -> {self.action}"
        if self.values:
            text += " (" + ", ".join(f"{k} {v:.3g}" for k, v in self.values) + ")"
        return text


#: One row of a device's edge table: (status bits, kind when they set, kind when they
#: clear, source).
Edge = tuple[int, EventKind, EventKind, str]


#: What `EdgeDetector.update` returns when nothing changed (shared: no list per frame).
_NO_EVENTS: tuple[RobotEvent, ...] = ()


class EdgeDetector:
    """Turns successive (status word, state) levels into edge events, from a table.

    The first word is compared with an all-clear status, so a fault present at connect
    time is reported; the state is reported on changes only (not the first one).

    Args:
        table: Which bits mean what; the device's own.
        state_changed: The kind of event a change of state makes, if the device has a
            state worth reporting.
    """

    def __init__(self, table: Sequence[Edge], state_changed: EventKind | None = None) -> None:
        self._table = tuple((int(bits), on, off, source) for bits, on, off, source in table)
        self._watched = 0
        for bits, *_ in self._table:
            self._watched |= bits
        self._state_changed = state_changed
        #: The last status word (a plain int: IntFlag arithmetic costs a microsecond
        #: per operation). With `state`, what a caller on the read
        #: path may compare a frame's levels with first, to skip the call when, as in
        #: nearly every frame, nothing changed.
        self.bits = 0
        #: The last state (``None`` before the first).
        self.state: enum.Enum | None = None

    def update(self, status: int, state: enum.Enum | None, ts: float) -> Sequence[RobotEvent]:
        """The edges between the previous levels and these (usually none)."""
        if status == self.bits and state is self.state:  # the usual case, every frame
            return _NO_EVENTS
        bits = int(status)
        events: list[RobotEvent] = []
        changed = (bits ^ self.bits) & self._watched
        # Kept whole, watched bits or not: a word that differs only in a bit nobody
        # watches (REMOTE_OFFLINE under host control) is then the usual case too.
        self.bits = bits
        if changed:
            for mask, on, off, source in self._table:
                if mask & changed:
                    events.append(RobotEvent(on if mask & bits else off, source, ts))
        if state is not self.state:
            if self.state is not None and self._state_changed is not None:
                events.append(RobotEvent(self._state_changed, "", ts, state=state))
            self.state = state
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
            return RobotEvent(EventKind.BATTERY_LOW, "", ts, voltage=voltage)
        if self.low and voltage >= self.threshold + self.hysteresis:
            self.low = False
            return RobotEvent(EventKind.BATTERY_OK, "", ts, voltage=voltage)
        return None
