"""The per-page protocol, sans-IO: what one page's message asks for, and what a page is
told (its ``hello``, the notes beside its states).

No socket, no event loop, no clock of its own: `Page.read` takes a message as it came
(bytes) and the server's monotonic clock reading, and returns the action it asks for
(`Drive`, `Stop`, `EStop` or `Request`) or raises `CommandError` saying why it is
refused. The server (``sockets.py``) does what the action says through the page's
motion-core source; the rules of driving are the core's.

The page clock: a drive message carries ``t``, milliseconds of the page's
``performance.now()``. A page keeps the least difference between the server's clock
and the page's (the fastest a message has come); a message later than that by more
than the deadman was held up (a stalled network delivering a backlog) and is refused;
a later one is given to the core that much old. No clock needs to agree with another.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from ...core.motion import Refusal
from ...core.validation import check_int, check_real
from ..inbound import CommandError, command_number, command_object

__all__ = [
    "DEFAULT_MAX_ANGULAR",
    "DEFAULT_MAX_LINEAR",
    "EVENTS_KEPT",
    "KINDS",
    "MAX_DEADZONE",
    "MAX_MESSAGE",
    "STOP_ACTIONS",
    "Action",
    "Drive",
    "EStop",
    "GamepadMapping",
    "Page",
    "Request",
    "Stop",
    "Terms",
    "limit",
    "offered",
    "refusal_text",
]

#: The widest gamepad deadzone taken (a fraction of full deflection).
MAX_DEADZONE = 0.95
#: What a page may ask for when neither the dashboard nor the device sets a limit
#: (m/s, rad/s): ``chassis-sdk drive``'s defaults, slow enough to walk beside.
DEFAULT_MAX_LINEAR = 0.5
DEFAULT_MAX_ANGULAR = 1.0
#: The largest message taken (a drive message is about 60 bytes).
MAX_MESSAGE = 4096
#: Events kept for a page that opens later (and, per page, not yet sent).
EVENTS_KEPT = 50
#: Every kind of message a page may send, offered or not.
KINDS = ("drive", "release", "clear_faults", "led", "buzzer", "stop", "estop")
#: What a read-only dashboard, and a stop-only page, offers.
STOP_ACTIONS = ("stop", "estop")


@dataclass(frozen=True, slots=True)
class GamepadMapping:
    """How the page reads a gamepad (the browser's Gamepad API, standard mapping), as
    teleop_twist_joy's parameters.

    Attributes:
        linear_axis: The axis for linear speed (``axes[1]``: the left stick's vertical;
            up is negative in the API, so it is inverted).
        angular_axis: The axis for turning (``axes[0]``: the left stick's horizontal;
            left turns counter-clockwise).
        enable_button: The button held to drive (``buttons[4]``: LB); released, the
            robot stops at once.
        scale_linear: Full deflection, as a fraction of ``max_linear``.
        scale_angular: Full deflection, as a fraction of ``max_angular``.
        deadzone: Deflections below it count as none.
        stale_after: Seconds without a new reading from the pad (its ``timestamp``
            unchanged) after which, while enabled, it counts as gone: the robot stops.
    """

    linear_axis: int = 1
    angular_axis: int = 0
    enable_button: int = 4
    scale_linear: float = 1.0
    scale_angular: float = 1.0
    deadzone: float = 0.1
    stale_after: float = 1.0

    def __post_init__(self) -> None:
        for name in ("linear_axis", "angular_axis", "enable_button"):
            check_int(getattr(self, name), name, low=0, high=63)
        for name in ("scale_linear", "scale_angular"):
            check_real(getattr(self, name), name, low=0, low_open=True, high=1)
        check_real(self.deadzone, "deadzone", low=0, high=MAX_DEADZONE)
        check_real(self.stale_after, "stale_after", low=0, low_open=True, high=10, unit="s")


def limit(name: str, given: float | None, device: float | None, default: float) -> float:
    """The limit pages are held to: ``given`` (never above the device's), else the
    device's, else ``default``.

    Raises:
        ValueError: ``given`` is not a positive number.
    """
    if given is None:
        return device if device is not None else default
    value = check_real(given, name, low=0, low_open=True)
    return value if device is None else min(value, device)


def offered(device: Any, read_only: bool, features: Mapping[str, Any]) -> tuple[str, ...]:
    """The actions the page offers, by what ``device`` has and the mode (without an
    e-stop, E-STOP stops)."""
    if read_only:
        return STOP_ACTIONS
    actions = [*STOP_ACTIONS, "drive"]
    if hasattr(device, "release_emergency_stop"):
        actions.append("release")
    if hasattr(device, "clear_faults"):
        actions.append("clear_faults")
    for name in ("led", "buzzer"):
        if features.get(name) and hasattr(device, f"set_{name}"):
            actions.append(name)
    return tuple(actions)


@dataclass(frozen=True, slots=True)
class Terms:
    """What the dashboard offers every page (the same for all of them)."""

    device_name: str
    read_only: bool
    #: The actions offered a page let in under the page limit.
    actions: tuple[str, ...]
    max_linear: float
    max_angular: float
    command_timeout: float
    rate: float
    gamepad: GamepadMapping
    features: Mapping[str, Any]
    #: Whether the device has an e-stop; without one, E-STOP only stops (and says so).
    estop: bool = True


@dataclass(frozen=True, slots=True)
class Drive:
    """A fresh velocity, ``age`` seconds old (later than the page's fastest delivery)."""

    linear: float
    angular: float
    age: float = 0.0


@dataclass(frozen=True, slots=True)
class Stop:
    """Stop now (the page let go of its controls)."""


@dataclass(frozen=True, slots=True)
class EStop:
    """The emergency stop (a plain stop on a device without one)."""


@dataclass(frozen=True, slots=True)
class Request:
    """Release, clear faults, LED or buzzer (``on`` for the last two)."""

    kind: str
    on: bool | None = None


Action = Drive | Stop | EStop | Request


def _keys(body: Mapping[str, Any], allowed: Iterable[str]) -> None:
    extra = set(body) - {"type", *allowed}
    if extra:
        raise CommandError(f"unknown keys {sorted(extra)!r} for {body['type']!r}")


class Page:
    """One page's side of the protocol: what it may do, its clock, and the events and
    notes it has not been sent yet.

    Args:
        name: How it is named in refusals and logs (its motion source's name).
        terms: What the dashboard offers.
        stop_only: Let in beyond the page limit: STOP and E-STOP only.
    """

    def __init__(self, name: str, terms: Terms, *, stop_only: bool = False) -> None:
        self.name = name
        self.terms = terms
        self.stop_only = stop_only
        self.actions = list(STOP_ACTIONS if stop_only else terms.actions)
        #: The least (server clock - page clock) seen: the fastest delivery.
        self.offset = math.inf
        self.last_t = -math.inf
        self.events: deque[dict[str, Any]] = deque(maxlen=EVENTS_KEPT)
        self.notes: deque[dict[str, Any]] = deque(maxlen=32)

    def read(self, raw: object, now: float) -> Action:
        """The action one message asks for; ``now`` is the server's monotonic clock
        (seconds) as it arrived.

        Raises:
            CommandError: Not a well-formed command this page may send (or held up).
        """
        body = command_object(raw, limit=MAX_MESSAGE)
        kind = body.get("type")
        if not isinstance(kind, str):
            raise CommandError("a message needs a string 'type'")
        if kind not in self.actions:
            if kind in KINDS:
                if self.stop_only:
                    mode = "stop only: the page limit is reached"
                elif self.terms.read_only:
                    mode = "read-only"
                else:
                    mode = f"a {self.terms.device_name}"
                raise CommandError(f"{kind!r} is not offered ({mode})")
            raise CommandError(f"unknown message type {kind[:40]!r}")
        if kind == "drive":
            _keys(body, ("linear", "angular", "t"))
            return self._drive(body, now)
        if kind in ("led", "buzzer"):
            _keys(body, ("on",))
            on = body.get("on")
            if not isinstance(on, bool):
                raise CommandError(f"{kind} needs 'on': true or false")
            return Request(kind, on)
        _keys(body, ())
        if kind == "stop":
            return Stop()
        if kind == "estop":
            return EStop()
        return Request(kind)

    def _drive(self, body: dict[str, Any], now: float) -> Drive:
        terms = self.terms
        linear, angular = command_number(body, "linear"), command_number(body, "angular")
        for name, value, most in (
            ("linear", linear, terms.max_linear),
            ("angular", angular, terms.max_angular),
        ):
            if abs(value) > most * (1 + 1e-9):
                raise CommandError(f"{name} {value:g} is beyond the limit {most:g}")
        if "t" not in body:
            return Drive(linear, angular)
        t = command_number(body, "t") / 1000.0
        if t < self.last_t:
            raise CommandError("t went back: messages out of order")
        self.last_t = t
        self.offset = min(self.offset, now - t)
        age = now - t - self.offset  # later than the fastest delivery
        if age > terms.command_timeout:
            raise CommandError(f"held up {age:.2f} s (longer than the deadman)")
        return Drive(linear, angular, age)

    def hello(
        self, port: str, events: Iterable[dict[str, Any]], path: Iterable[tuple[float, float]]
    ) -> dict[str, Any]:
        """The first message a page is sent: the device (on ``port``), what it may do,
        the limits, the gamepad, and the ``events`` and odometry ``path`` so far."""
        terms = self.terms
        return {
            "type": "hello",
            "device": terms.device_name,
            "port": port,
            "read_only": terms.read_only or self.stop_only,
            "stop_only": self.stop_only,
            "actions": self.actions,
            "estop": terms.estop,
            "max_linear": terms.max_linear,
            "max_angular": terms.max_angular,
            "command_timeout": terms.command_timeout,
            "rate": terms.rate,
            "gamepad": dataclasses.asdict(terms.gamepad),
            "features": dict(terms.features),
            "events": list(events),
            "path": [list(p) for p in path],
        }

    def refused(self, why: str, total: int) -> None:
        """Tell the page a message was refused (``total``: refusals so far, all pages)."""
        self.notes.append({"refused": why, "total": total})

    def done(self, what: str) -> None:
        """Tell the page a stop or request was done."""
        self.notes.append({"done": what})

    def with_news(self, state: str) -> str:
        """``state`` (JSON text, the same for every page) with this page's events and
        notes not yet sent, which it takes."""
        if not (self.events or self.notes):
            return state
        extra = {"events": list(self.events), "notes": list(self.notes)}
        self.events.clear()
        self.notes.clear()
        return state[:-1] + ", " + json.dumps(extra)[1:]


def refusal_text(refusal: Refusal) -> str:
    """What a page is told of a velocity the motion core refused."""
    if refusal.reason == "blocked" and any("ESTOP" in b for b in refusal.blocks):
        return f"the emergency stop is engaged: release it first ({refusal.detail})"
    return refusal.detail
