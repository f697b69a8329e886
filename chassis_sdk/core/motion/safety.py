"""Reflexes, sans-IO: what a device reports, checked against a `SafetyPolicy`, and what
to do about each hazard (stop, back off, slow down, or, only if allowed, nothing).

`Reflexes` takes observations with their timestamps (the bumpers, the measured and
commanded speeds, the pose, the IMU, the battery voltage, the link's silence) and
returns `Trigger` values: a hazard began (or ended) and the action its policy names.
It writes nothing and reads no clock;
[`ReflexRunner`][chassis_sdk.core.motion.reflexes.ReflexRunner] acts on what it returns,
through the motion core.

A hazard triggers once when it begins (an edge, as an event), and again only after it
has ended. The hazards:

========== ================================================ ===========================
hazard     begins when                                      actions
========== ================================================ ===========================
bumper     the front or rear bumper bit is set              stop, back_off, ignore
stall      commanded above `stall_speed`, measured below    stop, ignore
           `stall_ratio` of it, for `stall_time`
tilt       the IMU's gravity more than `tilt_angle` off     stop, slow, ignore
           where it was at the start, or an acceleration
           over `impact` g
geofence   the pose leaves the `Geofence`                   stop, slow, ignore
battery    the voltage below `battery_critical` (or the     stop, slow, ignore
           battery model's critical level)
link       no valid frame for `link_silence` while moving   stop, ignore
========== ================================================ ===========================
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, Literal

from ..validation import check_real

__all__ = [
    "ACTIONS",
    "HAZARDS",
    "Action",
    "Geofence",
    "Hazard",
    "Reflex",
    "Reflexes",
    "SafetyPolicy",
    "Trigger",
]

Hazard = Literal["bumper", "stall", "tilt", "geofence", "battery", "link"]
Action = Literal["stop", "back_off", "slow", "ignore"]

#: The hazards, and the actions each may take.
HAZARDS: Final[dict[str, tuple[str, ...]]] = {
    "bumper": ("stop", "back_off", "ignore"),
    "stall": ("stop", "ignore"),
    "tilt": ("stop", "slow", "ignore"),
    "geofence": ("stop", "slow", "ignore"),
    "battery": ("stop", "slow", "ignore"),
    "link": ("stop", "ignore"),
}
ACTIONS: Final = ("stop", "back_off", "slow", "ignore")
#: The time constant (s) of the low-pass that reads gravity from the accelerometer.
TILT_TIME: Final = 0.5
#: Outside the geofence, going this much (m) further out than the closest it came
#: since the last trigger triggers again.
FENCE_SLACK: Final = 0.02


@dataclass(frozen=True, slots=True)
class Reflex:
    """What to do about one hazard.

    Attributes:
        action: ``"stop"``, ``"back_off"`` (bumper: drive ``distance`` away, then stop),
            ``"slow"`` (cap the speed at ``speed`` while the hazard lasts) or
            ``"ignore"`` (only with ``allow_unsafe``).
        distance: How far ``back_off`` drives (m).
        speed: The cap of ``slow`` (m/s), and the speed of ``back_off``.
    """

    action: Action = "stop"
    distance: float = 0.1
    speed: float = 0.1

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(
                f"a reflex's action is one of {', '.join(ACTIONS)}, got {self.action!r}"
            )
        check_real(self.distance, "distance", low=0, low_open=True, unit="m")
        check_real(self.speed, "speed", low=0, low_open=True, unit="m/s")


@dataclass(frozen=True, slots=True)
class Geofence:
    """Where the robot may be, in the odometry frame: a polygon (``points``, at least
    three) or a circle (``centre`` and ``radius``)."""

    points: tuple[tuple[float, float], ...] = ()
    centre: tuple[float, float] | None = None
    radius: float | None = None

    def __post_init__(self) -> None:
        if self.radius is not None:
            check_real(self.radius, "radius", low=0, low_open=True, unit="m")
            if self.points:
                raise ValueError("a geofence is a polygon or a circle, not both")
            if self.centre is None:
                object.__setattr__(self, "centre", (0.0, 0.0))
        elif len(self.points) < 3:
            raise ValueError("a geofence needs a radius or at least three points")
        for x, y in (*self.points, *([self.centre] if self.centre else [])):
            check_real(x, "x", unit="m")
            check_real(y, "y", unit="m")

    @classmethod
    def rectangle(cls, width: float, height: float) -> Geofence:
        """A ``width`` x ``height`` rectangle centred on the origin."""
        w = check_real(width, "width", low=0, low_open=True, unit="m") / 2
        h = check_real(height, "height", low=0, low_open=True, unit="m") / 2
        return cls(((-w, -h), (w, -h), (w, h), (-w, h)))

    def outside_by(self, x: float, y: float) -> float:
        """How far ``(x, y)`` is outside (m); 0 inside or on the border."""
        if self.contains(x, y):
            return 0.0
        if self.radius is not None:
            cx, cy = self.centre or (0.0, 0.0)
            return math.hypot(x - cx, y - cy) - self.radius
        pts = self.points
        return min(_to_segment(x, y, a, b) for a, b in zip(pts, pts[1:] + pts[:1], strict=True))

    def contains(self, x: float, y: float) -> bool:
        """Whether ``(x, y)`` is inside (the border counts as inside)."""
        if self.radius is not None:
            cx, cy = self.centre or (0.0, 0.0)
            return math.hypot(x - cx, y - cy) <= self.radius
        inside = False
        pts = self.points
        for (x1, y1), (x2, y2) in zip(pts, pts[1:] + pts[:1], strict=True):
            if (y1 > y) != (y2 > y):
                at = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
                if x == at:
                    return True
                if x < at:
                    inside = not inside
        return inside


@dataclass(frozen=True, slots=True)
class SafetyPolicy:
    """A device's reflexes: per hazard a `Reflex`, and the thresholds.

    The defaults are safe: every hazard stops the robot; the geofence and the battery
    threshold are off until given. ``ignore`` needs ``allow_unsafe=True``, and is then
    announced at the start and as an event.

    Raises:
        ValueError: A hazard given an action it cannot take, ``ignore`` without
            ``allow_unsafe``, or a bad threshold.
    """

    bumper: Reflex = field(default_factory=Reflex)
    stall: Reflex = field(default_factory=Reflex)
    tilt: Reflex = field(default_factory=Reflex)
    geofence: Reflex = field(default_factory=Reflex)
    battery: Reflex = field(default_factory=Reflex)
    link: Reflex = field(default_factory=Reflex)
    #: Commanded speed (m/s) above which a stall is watched for.
    stall_speed: float = 0.05
    #: Measured below this share of the commanded speed counts as stalled.
    stall_ratio: float = 0.2
    #: How long a stall must last (s).
    stall_time: float = 0.5
    #: Tilt beyond this (degrees from vertical) is a hazard.
    tilt_angle: float = 20.0
    #: An acceleration beyond this (g, gravity taken off) is an impact.
    impact: float = 2.0
    #: Where the robot may go, or ``None``.
    fence: Geofence | None = None
    #: Voltage below which the battery is critical, or ``None`` (the battery model's
    #: critical level still counts).
    battery_critical: float | None = None
    #: No valid frame for this long (s) while moving is a degraded link.
    link_silence: float = 0.5
    allow_unsafe: bool = False

    def __post_init__(self) -> None:
        for hazard, actions in HAZARDS.items():
            reflex = getattr(self, hazard)
            if not isinstance(reflex, Reflex):
                raise TypeError(f"{hazard} must be a Reflex, got {reflex!r}")
            if reflex.action not in actions:
                raise ValueError(f"{hazard} cannot {reflex.action}: it takes {', '.join(actions)}")
            if reflex.action == "ignore" and not self.allow_unsafe:
                raise ValueError(f"ignoring the {hazard} needs allow_unsafe=True")
        check_real(self.stall_speed, "stall_speed", low=0, low_open=True, unit="m/s")
        check_real(self.stall_ratio, "stall_ratio", low=0, high=1)
        check_real(self.stall_time, "stall_time", low=0, low_open=True, unit="s")
        check_real(self.tilt_angle, "tilt_angle", low=0, low_open=True, high=90)
        check_real(self.impact, "impact", low=0, low_open=True)
        check_real(self.link_silence, "link_silence", low=0, low_open=True, unit="s")
        if self.battery_critical is not None:
            check_real(self.battery_critical, "battery_critical", low=0, low_open=True, unit="V")
        if self.fence is not None and not isinstance(self.fence, Geofence):
            raise TypeError(f"fence must be a Geofence or None, got {self.fence!r}")

    @property
    def ignored(self) -> tuple[str, ...]:
        """The hazards this policy ignores (announced at start)."""
        return tuple(h for h in HAZARDS if getattr(self, h).action == "ignore")


@dataclass(frozen=True, slots=True)
class Trigger:
    """A hazard began (``began``) or ended, and what to do.

    Attributes:
        hazard: ``"bumper"``, ``"stall"``...
        source: Which one, where there are several (``"front"``, ``"rear"``), else ``""``.
        reflex: The policy's reflex for it.
        began: True when it began, False when it ended.
        timestamp: The observation's time.
        values: What was measured (``(("tilt", 31.2),)``).
    """

    hazard: str
    source: str
    reflex: Reflex
    began: bool
    timestamp: float
    values: tuple[tuple[str, float], ...] = ()

    @property
    def block(self) -> str:
        """The block's name while a ``stop`` holds (``"REFLEX_STALL"``)."""
        return f"REFLEX_{self.hazard.upper()}"


def _to_segment(x: float, y: float, a: tuple[float, float], b: tuple[float, float]) -> float:
    """The distance from ``(x, y)`` to the segment ``a``-``b``."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((x - a[0]) * dx + (y - a[1]) * dy) / length2))
    return math.hypot(x - a[0] - t * dx, y - a[1] - t * dy)


def _angle(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """Degrees between two vectors (0 if either is zero)."""
    na, nb = math.hypot(*a), math.hypot(*b)
    if na == 0 or nb == 0:
        return 0.0
    cos = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (na * nb)
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


class Reflexes:
    """The hazards' states, and the triggers of each observation (see the module)."""

    def __init__(self, policy: SafetyPolicy) -> None:
        if not isinstance(policy, SafetyPolicy):
            raise TypeError(f"safety must be a SafetyPolicy, got {policy!r}")
        self.policy = policy
        self._on: dict[tuple[str, str], bool] = {}
        self._stalled_since: float | None = None
        self._gravity: tuple[float, float, float] | None = None
        self._imu_time = -math.inf
        self._first_imu: float | None = None
        self._level: tuple[float, float, float] | None = None
        self._fence_least = math.inf

    @property
    def stalling(self) -> bool:
        """Whether a stall is being timed or holds."""
        return self._stalled_since is not None or self.active("stall")

    def active(self, hazard: str, source: str = "") -> bool:
        """Whether ``hazard`` (from ``source``) holds now."""
        return self._on.get((hazard, source), False)

    def _edge(
        self,
        hazard: str,
        source: str,
        on: bool,
        now: float,
        values: Sequence[tuple[str, float]] = (),
    ) -> list[Trigger]:
        key = (hazard, source)
        if self._on.get(key, False) == on:
            return []
        self._on[key] = on
        reflex: Reflex = getattr(self.policy, hazard)
        return [Trigger(hazard, source, reflex, on, now, tuple(values))]

    def bumpers(self, front: bool, rear: bool, now: float) -> list[Trigger]:
        """The bumper bits as the device reports them."""
        return self._edge("bumper", "front", front, now) + self._edge("bumper", "rear", rear, now)

    def speeds(self, commanded: float, measured: float, now: float) -> list[Trigger]:
        """The commanded (as written) and measured linear speed (m/s), each sample."""
        p = self.policy
        stalled = abs(commanded) >= p.stall_speed and (
            measured * commanded <= 0 or abs(measured) < p.stall_ratio * abs(commanded)
        )
        if not stalled:
            self._stalled_since = None
            return self._edge("stall", "", False, now) if self.active("stall") else []
        if self._stalled_since is None:
            self._stalled_since = now
        if now - self._stalled_since < p.stall_time:
            return []
        values = (
            ("commanded", commanded),
            ("measured", measured),
            ("for", now - self._stalled_since),
        )
        return self._edge("stall", "", True, now, values)

    def imu(self, ax: float, ay: float, az: float, now: float) -> list[Trigger]:
        """An IMU sample's acceleration (g). The tilt is gravity's angle (the samples
        low-passed over `TILT_TIME`: a hard stop leans no board) from where it was at
        the start (level, however the IMU is mounted); an impact is a sample that far
        from that gravity."""
        g = self._gravity
        if g is None:
            g = (ax, ay, az)
        elif now > self._imu_time:  # samples of one read share its time: no time passed
            k = min(1.0, (now - self._imu_time) / TILT_TIME)
            g = (g[0] + k * (ax - g[0]), g[1] + k * (ay - g[1]), g[2] + k * (az - g[2]))
        self._gravity, self._imu_time = g, max(now, self._imu_time)
        if self._level is None:
            if self._first_imu is None:
                self._first_imu = now
            if now - self._first_imu >= TILT_TIME:
                self._level = g
        p = self.policy
        tilt = 0.0 if self._level is None else _angle(g, self._level)
        # In g whatever the IMU's scale: measured against gravity's own size.
        unit = math.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2) or 1.0
        shock = math.sqrt((ax - g[0]) ** 2 + (ay - g[1]) ** 2 + (az - g[2]) ** 2) / unit
        on = tilt > p.tilt_angle or shock > p.impact
        if not on and not self.active("tilt"):
            return []
        return self._edge("tilt", "", on, now, (("tilt", tilt), ("impact", shock)))

    def pose(self, x: float, y: float, now: float) -> list[Trigger]:
        """The odometry pose (m). Leaving the fence triggers; while outside, going
        further out than `FENCE_SLACK` beyond the closest it came since triggers again
        (driving back in never does)."""
        fence = self.policy.fence
        if fence is None:
            return []
        out = fence.outside_by(x, y)
        values = (("x", x), ("y", y), ("outside", out))
        if out <= 0.0:
            self._fence_least = math.inf
            return self._edge("geofence", "", False, now, values)
        if not self.active("geofence"):
            self._fence_least = out
            return self._edge("geofence", "", True, now, values)
        if out < self._fence_least:
            self._fence_least = out
            return []
        if out - self._fence_least <= FENCE_SLACK:
            return []
        self._fence_least = out
        return [Trigger("geofence", "", self.policy.geofence, True, now, values)]

    def voltage(self, volts: float, now: float, critical: bool = False) -> list[Trigger]:
        """A battery reading; ``critical``: the battery model says so. Ends 0.2 V above."""
        limit = self.policy.battery_critical
        low = critical or (limit is not None and volts < limit)
        if not low and self.active("battery") and limit is not None and volts < limit + 0.2:
            return []  # hysteresis: a sagging battery does not chatter
        return self._edge("battery", "", low, now, (("voltage", volts),))

    def link(self, silence: float | None, moving: bool, now: float) -> list[Trigger]:
        """The time since the last valid frame (``None``: none yet), while a command is
        in force (``moving``)."""
        if not moving:  # only seen while moving: re-armed for the next command
            self._on.pop(("link", ""), None)
            return []
        on = silence is not None and silence > self.policy.link_silence
        return self._edge("link", "", on, now, (("silence", silence or 0.0),))

    def rearm(self, hazard: str) -> None:
        """Forget that ``hazard`` holds: it triggers again when next seen."""
        for key in [k for k in self._on if k[0] == hazard]:
            del self._on[key]
        if hazard == "stall":
            self._stalled_since = None
