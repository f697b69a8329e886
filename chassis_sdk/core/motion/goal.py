"""Goals as plans, sans-IO: drive a distance, turn an angle, go to a pose.

A plan takes the odometry samples one by one (`Plan.step`) and answers with the
velocity to command, or ``None`` once it is within tolerance. Its clock is the samples'
timestamps; it writes nothing and never sleeps. [`run_goal`][chassis_sdk.core.motion.goals.run_goal]
runs one on a device, through the motion core, as a source of kind ``"goal"``.

A plan aims at a quarter of its tolerance, so the robot at rest is well within it.
The speed follows a trapezoid: up at the acceleration, at most the cruise speed, down
so as to stop on the target (``v = sqrt(2 * deceleration * remaining)``, the remaining
distance shortened by what the robot covers before a command takes effect), and at
least a creep speed until it is within tolerance, so it never stalls short of it.
Heading is held on a line by steering towards it (a stanley-like law); a go-to faces the
point, drives the line to it, then turns to the heading if one is given.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final, Literal, Protocol

from ..odometry import Odometry, wrap_angle

__all__ = [
    "DEFAULT_ANGULAR",
    "DEFAULT_LINEAR",
    "Line",
    "MoveEnd",
    "MoveResult",
    "Plan",
    "Pose",
    "Profile",
    "Steps",
    "Turn",
    "go_to",
    "speed_for",
]


class Pose(Protocol):
    """What a plan reads of an odometry sample (an [`Odometry`][chassis_sdk.Odometry])."""

    @property
    def x(self) -> float: ...
    @property
    def y(self) -> float: ...
    @property
    def heading(self) -> float: ...
    @property
    def timestamp(self) -> float: ...


#: How a goal ended, where a `MoveResult` tells it: within tolerance (returned), its
#: timeout (`MoveTimeoutError.result`), another source, a stop or a newer goal
#: (`MovePreemptedError.result`). A block (an e-stop, a bumper, a reflex) raises
#: `MotionBlockedError`; cancelling raises ``CancelledError``.
MoveEnd = Literal["done", "timeout", "preempted"]


@dataclass(frozen=True, slots=True)
class MoveResult:
    """How a goal ended.

    Attributes:
        pose: The last odometry sample (after the robot came to rest, for a goal that
            ended ``"done"``), or ``None`` if none came.
        error: What was left: metres for ``drive_distance`` (signed, along the line)
            and ``go_to`` (to the point), radians for ``rotate`` (signed).
        duration: Seconds from the call to the end.
        ended: ``"done"``, ``"timeout"`` or ``"preempted"``.
        heading_error: Radians left to the goal's heading (``go_to`` with a heading,
            ``rotate``), else 0.
    """

    pose: Odometry | None
    error: float
    duration: float
    ended: MoveEnd
    heading_error: float = 0.0


@dataclass(frozen=True, slots=True)
class Profile:
    """One axis's speed profile: cruise speed, ramps, creep, and the lag it anticipates.

    Attributes:
        speed: Cruise speed (m/s or rad/s), > 0.
        acceleration: Ramp up (per s), > 0.
        deceleration: Ramp down towards the target (per s), > 0.
        creep: The least speed while outside tolerance.
        lag: Seconds from a command to its effect on odometry (a write period and a
            telemetry period): the distance covered in it is taken off the remaining.
    """

    speed: float
    acceleration: float
    deceleration: float
    creep: float
    lag: float = 0.04


#: Defaults: 0.3 m/s at 0.5 m/s², creeping at 2 cm/s; 0.8 rad/s at 2 rad/s², 0.05 rad/s.
DEFAULT_LINEAR: Final = Profile(0.3, 0.5, 0.5, 0.02)
DEFAULT_ANGULAR: Final = Profile(0.8, 2.0, 2.0, 0.05)


def speed_for(remaining: float, previous: float, profile: Profile, dt: float) -> float:
    """The signed speed towards ``remaining`` (same sign), from ``previous`` (the last
    command on this axis) after ``dt`` seconds."""
    ahead = abs(remaining) - abs(previous) * profile.lag
    braking = math.sqrt(2.0 * profile.deceleration * max(ahead, 0.0))
    # Ramp up from the last command if it went the same way, else from rest.
    base = abs(previous) if previous * remaining > 0 else 0.0
    speed = min(profile.speed, braking, base + profile.acceleration * max(dt, 0.0))
    return math.copysign(max(speed, min(profile.creep, profile.speed)), remaining)


def _within(left: float, tolerance: float, profile: Profile) -> bool:
    """Done: within a quarter of the tolerance (what the creep covers in the lag at
    least), so that the robot at rest is well within it."""
    return abs(left) <= max(tolerance / 4, profile.creep * profile.lag)


class Plan(Protocol):
    """A goal's plan: `step` each odometry sample; ``None`` once it is done."""

    def step(self, pose: Pose) -> tuple[float, float] | None: ...

    def error(self, pose: Pose) -> tuple[float, float]:
        """(what is left in the goal's unit, radians left to its heading)."""
        ...


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class Turn:
    """Turn in place: by ``angle`` (radians, any size, counter-clockwise positive) from
    the first sample, or to the absolute ``heading`` (the shorter way)."""

    def __init__(
        self,
        profile: Profile,
        tolerance: float,
        *,
        angle: float | None = None,
        heading: float | None = None,
    ) -> None:
        if (angle is None) == (heading is None):
            raise ValueError("a turn takes an angle or a heading")
        self.profile = profile
        self.tolerance = tolerance
        self._angle = angle
        self._heading = heading
        self._turned = 0.0
        self._last: float | None = None  # the last sample's heading
        self._time: float | None = None
        self._w = 0.0

    def _left(self, pose: Pose) -> float:
        if self._heading is not None:
            return wrap_angle(self._heading - pose.heading)
        if self._last is not None:
            self._turned += wrap_angle(pose.heading - self._last)
        self._last = pose.heading
        assert self._angle is not None
        return self._angle - self._turned

    def step(self, pose: Pose) -> tuple[float, float] | None:
        left = self._left(pose)
        dt = 0.0 if self._time is None else pose.timestamp - self._time
        self._time = pose.timestamp
        if _within(left, self.tolerance, self.profile):
            self._w = 0.0
            return None
        self._w = speed_for(left, self._w, self.profile, dt)
        return (0.0, self._w)

    def error(self, pose: Pose) -> tuple[float, float]:
        if self._heading is not None:
            left = wrap_angle(self._heading - pose.heading)
        else:
            assert self._angle is not None
            last = pose.heading if self._last is None else self._last
            left = self._angle - self._turned - wrap_angle(pose.heading - last)
        return left, left


class Line:
    """Drive ``distance`` metres (negative: backwards) along the line through ``start``
    at ``direction`` (radians), steering back onto it."""

    #: Steering: heading correction per metre off the line (atan-shaped), and per radian.
    CROSS_GAIN: Final = 2.0
    HEADING_GAIN: Final = 3.0

    def __init__(
        self,
        start: tuple[float, float],
        direction: float,
        distance: float,
        linear: Profile,
        angular: Profile,
        tolerance: float,
    ) -> None:
        self._x0, self._y0 = start
        self._h = direction
        self._cos, self._sin = math.cos(direction), math.sin(direction)
        self.distance = distance
        self.linear = linear
        self.angular = angular
        self.tolerance = tolerance
        self._time: float | None = None
        self._v = 0.0

    def _along(self, pose: Pose) -> tuple[float, float]:
        dx, dy = pose.x - self._x0, pose.y - self._y0
        return dx * self._cos + dy * self._sin, -dx * self._sin + dy * self._cos

    def step(self, pose: Pose) -> tuple[float, float] | None:
        along, across = self._along(pose)
        left = self.distance - along
        dt = 0.0 if self._time is None else pose.timestamp - self._time
        self._time = pose.timestamp
        if _within(left, self.tolerance, self.linear):
            self._v = 0.0
            return None
        self._v = speed_for(left, self._v, self.linear, dt)
        # Steer onto the line: backwards, the same correction turns the other way.
        sign = 1.0 if self._v >= 0 else -1.0
        want = self._h - sign * math.atan(self.CROSS_GAIN * across)
        w = self.HEADING_GAIN * wrap_angle(want - pose.heading)
        return (self._v, _clamp(w, self.angular.speed))

    def error(self, pose: Pose) -> tuple[float, float]:
        along, _ = self._along(pose)
        return self.distance - along, 0.0


class Steps:
    """Plans one after the other, each made from the sample on which the one before
    finished (a go-to: face the point, drive to it, turn to the heading)."""

    def __init__(
        self,
        makers: Sequence[Callable[[Pose], Plan | None]],
        error: Callable[[Pose], tuple[float, float]],
    ) -> None:
        self._makers = list(makers)
        self._plan: Plan | None = None
        self._error = error

    def step(self, pose: Pose) -> tuple[float, float] | None:
        while True:
            if self._plan is None:
                if not self._makers:
                    return None
                self._plan = self._makers.pop(0)(pose)
                if self._plan is None:
                    continue
            command = self._plan.step(pose)
            if command is not None:
                return command
            self._plan = None

    def error(self, pose: Pose) -> tuple[float, float]:
        return self._error(pose)


def go_to(
    x: float,
    y: float,
    heading: float | None,
    linear: Profile,
    angular: Profile,
    tolerance: float,
    angle_tolerance: float,
) -> Steps:
    """The plan to the point ``(x, y)`` (and ``heading``, if given) in the odometry frame."""

    def face(pose: Pose) -> Plan | None:
        if math.hypot(x - pose.x, y - pose.y) <= tolerance:
            return None
        bearing = math.atan2(y - pose.y, x - pose.x)
        # Facing within 2° is enough: the line's steering takes up the rest.
        return Turn(angular, max(angle_tolerance, math.radians(2.0)), heading=bearing)

    def drive(pose: Pose) -> Plan | None:
        distance = math.hypot(x - pose.x, y - pose.y)
        if distance <= tolerance:
            return None
        bearing = math.atan2(y - pose.y, x - pose.x)
        return Line((pose.x, pose.y), bearing, distance, linear, angular, tolerance)

    def turn(_pose: Pose) -> Plan | None:
        if heading is None:
            return None
        return Turn(angular, angle_tolerance, heading=heading)

    def error(pose: Pose) -> tuple[float, float]:
        off = 0.0 if heading is None else wrap_angle(heading - pose.heading)
        return math.hypot(x - pose.x, y - pose.y), off

    return Steps([face, drive, turn], error)
