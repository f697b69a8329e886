"""The reflexes' rules, sans-IO: observations with their timestamps (an injected clock),
and the triggers they give; the policy's checks; the runner's actions on a `Motion`
with a fake clock (what reaches the wire). The reflexes on the simulators are in
``test_reflexes.py``."""

from __future__ import annotations

import logging
import math
from types import SimpleNamespace
from typing import Any

import pytest

from chassis_sdk import EventKind, Geofence, Reflex, RobotEvent, SafetyPolicy
from chassis_sdk.core.motion import Motion
from chassis_sdk.core.motion.reflexes import ReflexRunner
from chassis_sdk.core.motion.safety import Reflexes

pytestmark = pytest.mark.codec  # pure: no I/O, an injected clock


def edges(triggers: list[Any]) -> list[tuple[str, str, bool]]:
    return [(t.hazard, t.source, t.began) for t in triggers]


# Each row: a policy, a script of (method, *arguments) observations, and the edges.
ROWS: list[tuple[str, SafetyPolicy, list[tuple[Any, ...]], list[tuple[str, str, bool]]]] = [
    (
        "a bumper triggers once when hit, and ends when it clears",
        SafetyPolicy(),
        [
            ("bumpers", False, False, 0.0),
            ("bumpers", True, False, 0.02),
            ("bumpers", True, False, 0.04),
            ("bumpers", False, False, 0.06),
        ],
        [("bumper", "front", True), ("bumper", "front", False)],
    ),
    (
        "a stall: commanded, not moving, for stall_time",
        SafetyPolicy(),
        [("speeds", 0.3, 0.0, 0.0), ("speeds", 0.3, 0.01, 0.3), ("speeds", 0.3, 0.0, 0.5)],
        [("stall", "", True)],
    ),
    (
        "accelerating is no stall: measured rises past the ratio",
        SafetyPolicy(),
        [("speeds", 0.3, 0.0, 0.0), ("speeds", 0.3, 0.07, 0.1), ("speeds", 0.3, 0.3, 0.6)],
        [],
    ),
    (
        "a stall broken before stall_time is forgotten",
        SafetyPolicy(),
        [
            ("speeds", 0.3, 0.0, 0.0),
            ("speeds", 0.3, 0.3, 0.4),
            ("speeds", 0.3, 0.0, 0.6),
            ("speeds", 0.3, 0.0, 1.0),
        ],
        [],
    ),
    (
        "driven backwards against the command is a stall",
        SafetyPolicy(),
        [("speeds", 0.3, -0.2, 0.0), ("speeds", 0.3, -0.2, 0.6)],
        [("stall", "", True)],
    ),
    (
        "a creep below stall_speed is never a stall",
        SafetyPolicy(),
        [("speeds", 0.04, 0.0, 0.0), ("speeds", 0.04, 0.0, 2.0)],
        [],
    ),
    (
        "tilt: gravity 30° off where it was at the start (low-passed)",
        SafetyPolicy(),
        [
            ("imu", 0.0, 0.0, 1.0, 0.0),
            ("imu", 0.0, 0.0, 1.0, 0.5),
            ("imu", 0.5, 0.0, 0.866, 1.0),
            ("imu", 0.5, 0.0, 0.866, 2.0),
            ("imu", 0.0, 0.0, 1.0, 3.0),
            ("imu", 0.0, 0.0, 1.0, 4.0),
        ],
        [("tilt", "", True), ("tilt", "", False)],
    ),
    (
        "an IMU mounted on its side: that is level",
        SafetyPolicy(),
        [("imu", 1.0, 0.0, 0.0, 0.0), ("imu", 1.0, 0.0, 0.0, 0.6), ("imu", 1.0, 0.0, 0.0, 3.0)],
        [],
    ),
    (
        "a hard stop (0.5 g for one sample) tilts nothing",
        SafetyPolicy(),
        [
            ("imu", 0.0, 0.0, 1.0, 0.0),
            ("imu", 0.0, 0.0, 1.0, 0.6),
            ("imu", -0.5, 0.0, 1.0, 0.61),
            ("imu", 0.0, 0.0, 1.0, 0.62),
        ],
        [],
    ),
    (
        "two samples of one read (one time) lean nothing: no time passed between them",
        SafetyPolicy(),
        [
            ("imu", 0.0, 0.0, 1.0, 0.0),
            ("imu", 0.0, 0.0, 1.0, 0.6),
            ("imu", -0.4, 0.0, 1.0, 0.61),
            ("imu", -0.4, 0.0, 1.0, 0.61),
            ("imu", 0.0, 0.0, 1.0, 0.62),
        ],
        [],
    ),
    (
        "an IMU in counts (100 a g): half a g of vibration is no impact, 3 g is",
        SafetyPolicy(),
        [
            ("imu", 0.0, 0.0, 100.0, 0.0),
            ("imu", 50.0, 0.0, 100.0, 0.01),
            ("imu", 0.0, 0.0, 100.0, 0.02),
            ("imu", 300.0, 0.0, 100.0, 0.03),
        ],
        [("tilt", "", True)],
    ),
    (
        "an impact: 3 g in one sample",
        SafetyPolicy(),
        [("imu", 0.0, 0.0, 1.0, 0.0), ("imu", 3.0, 0.0, 1.0, 0.01)],
        [("tilt", "", True)],
    ),
    (
        "the geofence: leaving it, 19 cm further out (again), and coming back",
        SafetyPolicy(fence=Geofence.rectangle(2.0, 2.0)),
        [
            ("pose", 0.5, 0.5, 0.0),
            ("pose", 1.01, 0.5, 0.1),
            ("pose", 1.2, 0.5, 0.2),
            ("pose", 0.9, 0.5, 0.3),
        ],
        [("geofence", "", True), ("geofence", "", True), ("geofence", "", False)],
    ),
    (
        "outside, going further out triggers again; coming back never does",
        SafetyPolicy(fence=Geofence.rectangle(2.0, 2.0)),
        [
            ("pose", 1.05, 0.0, 0.0),
            ("pose", 1.04, 0.0, 0.1),
            ("pose", 1.055, 0.0, 0.2),
            ("pose", 1.07, 0.0, 0.3),
            ("pose", 1.08, 0.0, 0.4),
            ("pose", 0.9, 0.0, 0.5),
        ],
        [("geofence", "", True), ("geofence", "", True), ("geofence", "", False)],
    ),
    (
        "a circular geofence",
        SafetyPolicy(fence=Geofence(centre=(1.0, 0.0), radius=0.5)),
        [("pose", 1.0, 0.0, 0.0), ("pose", 1.0, 0.6, 0.1)],
        [("geofence", "", True)],
    ),
    (
        "no geofence: nothing",
        SafetyPolicy(),
        [("pose", 100.0, 100.0, 0.0)],
        [],
    ),
    (
        "battery critical below the voltage, over 0.2 V above it again",
        SafetyPolicy(battery_critical=22.0),
        [
            ("voltage", 23.0, 0.0),
            ("voltage", 21.9, 1.0),
            ("voltage", 22.1, 2.0),
            ("voltage", 22.3, 3.0),
        ],
        [("battery", "", True), ("battery", "", False)],
    ),
    (
        "the battery model's critical level counts without a voltage",
        SafetyPolicy(),
        [("voltage", 23.0, 0.0, True), ("voltage", 23.0, 1.0, False)],
        [("battery", "", True), ("battery", "", False)],
    ),
    (
        "the link: silent past link_silence while moving",
        SafetyPolicy(),
        [("link", 0.05, True, 0.0), ("link", 0.6, True, 0.6), ("link", 0.01, True, 0.7)],
        [("link", "", True), ("link", "", False)],
    ),
    (
        "a silent link while nothing moves is not the reflex's",
        SafetyPolicy(),
        [("link", 5.0, False, 0.0)],
        [],
    ),
]


@pytest.mark.parametrize(("rule", "policy", "script", "expected"), ROWS, ids=[r[0] for r in ROWS])
def test_reflex_rules(
    rule: str, policy: SafetyPolicy, script: list[tuple[Any, ...]], expected: list[Any]
) -> None:
    rules = Reflexes(policy)
    got = []
    for method, *args in script:
        got += edges(getattr(rules, method)(*args))
    assert got == expected, rule


@pytest.mark.parametrize(
    ("build", "error", "match"),
    [
        (lambda: SafetyPolicy(stall=Reflex("back_off")), ValueError, "stall cannot back_off"),
        (lambda: SafetyPolicy(bumper=Reflex("ignore")), ValueError, "allow_unsafe"),
        (
            lambda: Reflex("run away"),  # type: ignore[arg-type]
            ValueError,
            "one of stop, back_off, slow, ignore",
        ),
        (lambda: Reflex("back_off", distance=-1), ValueError, "distance"),
        (lambda: SafetyPolicy(tilt_angle=95), ValueError, "tilt_angle"),
        (lambda: SafetyPolicy(battery_critical=math.nan), ValueError, "battery_critical"),
        (lambda: SafetyPolicy(bumper="stop"), TypeError, "Reflex"),  # type: ignore[arg-type]
        (lambda: Geofence(((0, 0), (1, 0))), ValueError, "three points"),
        (lambda: Geofence(((0, 0), (1, 0), (1, 1)), radius=1.0), ValueError, "not both"),
    ],
)
def test_a_bad_policy_says_what_is_wrong(build: Any, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        build()


def test_ignoring_needs_allow_unsafe_and_is_announced() -> None:
    policy = SafetyPolicy(stall=Reflex("ignore"), allow_unsafe=True)
    assert policy.ignored == ("stall",)
    rig = Rig(policy)
    rig.runner.announce(0.0)
    assert [(e.kind, e.source) for e in rig.events] == [(EventKind.SAFETY_OVERRIDDEN, "stall")]


class Rig:
    """A `Motion` on a fake clock with a `ReflexRunner`, recording writes and events."""

    def __init__(self, policy: SafetyPolicy) -> None:
        self.t = 0.0
        self.writes: list[tuple[float, tuple[float, float]]] = []
        self.events: list[RobotEvent] = []
        self.motion = Motion(
            self._write,
            lambda: None,
            lambda: b"0,0",
            lambda a, b: lambda x, y: f"{x},{y}".encode(),
            interval=0.05,
            command_timeout=0.5,
            logger=logging.getLogger("test_reflex_rules"),
            clock=lambda: self.t,
        )
        self.runner = ReflexRunner(
            self.motion,
            policy,
            self.events.append,
            pose=lambda: self.odometry,
            logger=logging.getLogger("test"),
        )
        self.odometry: Any = None

    def pose(self, x: float, y: float, now: float) -> None:
        """A velocity sample (at rest) with the odometry at ``(x, y)``."""
        self.odometry = SimpleNamespace(x=x, y=y)
        self.runner.moved(0.0, now)

    def _write(self, frame: bytes, expires: float) -> None:
        a, b = (float(x) for x in frame.decode().split(","))
        self.writes.append((self.t, (a, b)))


def test_a_stall_writes_zero_in_the_same_call_and_ends_the_command() -> None:
    rig = Rig(SafetyPolicy())
    page = rig.motion.source("web page", kind="web")
    assert page.set_velocity(0.3, 0.0) is None
    rig.runner.moved(0.0, 0.0)
    rig.t = 0.45
    assert page.set_velocity(0.3, 0.0) is None  # the stick still held
    rig.t = 0.5
    rig.runner.moved(0.0, 0.5)
    assert rig.writes[-1] == (0.5, (0.0, 0.0))
    assert rig.motion.watchdog.active is None
    assert [(e.kind, e.source, e.action) for e in rig.events] == [
        (EventKind.REFLEX, "stall", "stop")
    ]
    assert rig.motion.blocks == ()  # a stall blocks only at its start: drive it clear
    refusal = page.set_velocity(0.3, 0.0)
    assert refusal is not None
    assert refusal.reason == "neutral"  # a stick must let go first
    assert page.set_velocity(0.0, 0.0) is None
    assert page.set_velocity(-0.2, 0.0) is None


def test_a_tilt_blocks_while_it_lasts() -> None:
    rig = Rig(SafetyPolicy())
    for t in (0.0, 0.6):
        rig.runner.imu(0.0, 0.0, 1.0, t)
    rig.runner.imu(0.0, 0.7, 0.7, 2.0)
    assert rig.motion.blocks == ("REFLEX_TILT",)
    rig.runner.imu(0.0, 0.0, 1.0, 3.0)
    rig.runner.imu(0.0, 0.0, 1.0, 5.0)
    assert not rig.motion.blocks
    assert [e.kind for e in rig.events] == [EventKind.REFLEX, EventKind.REFLEX_ENDED]


def test_slow_caps_every_command_while_the_battery_is_critical() -> None:
    rig = Rig(SafetyPolicy(battery=Reflex("slow", speed=0.1), battery_critical=22.0))
    api = rig.motion.api
    rig.runner.voltage(21.0, 0.0)
    assert api.set_velocity(0.5, 0.0) is None
    assert rig.writes[-1][1] == (0.1, 0.0)
    assert rig.motion.limits.max_linear is None  # the device's own limits are untouched
    rig.runner.voltage(23.0, 1.0)
    rig.t = 1.0
    assert api.set_velocity(0.5, 0.0) is None
    rig.t = 1.05
    rig.motion.watchdog.tick(1.05)
    assert rig.writes[-1][1] == (0.5, 0.0)


def test_clear_rearms_what_acts_once_and_keeps_what_lasts() -> None:
    rig = Rig(SafetyPolicy(battery_critical=22.0, fence=Geofence.rectangle(2.0, 2.0)))
    rig.runner.voltage(21.0, 0.0)
    rig.pose(1.5, 0.0, 0.0)
    assert rig.motion.blocks == ("REFLEX_BATTERY",)
    assert rig.runner.count == {"battery": 1, "geofence": 1}
    rig.runner.clear()
    assert rig.motion.blocks == ("REFLEX_BATTERY",)  # still critical: still blocked
    rig.pose(1.5, 0.0, 1.0)  # still outside: seen again, it triggers again
    assert rig.runner.count == {"battery": 1, "geofence": 2}


def test_a_silent_link_stops_every_new_command() -> None:
    rig = Rig(SafetyPolicy())
    api = rig.motion.api
    for attempt in (1, 2):
        assert api.set_velocity(0.3, 0.0, duration=5.0) is None
        assert rig.runner.link(0.6, rig.t) is True  # its first resend: silence counts from here
        rig.t += 0.55
        assert rig.runner.link(1.15, rig.t) is False  # half a second on: stopped
        assert rig.motion.watchdog.active is None
        assert rig.writes[-1][1] == (0.0, 0.0)
        assert rig.runner.count == {"link": attempt}
        rig.t += 0.1


def test_a_resend_held_up_by_the_hosts_loop_does_not_judge_the_link() -> None:
    rig = Rig(SafetyPolicy())
    assert rig.motion.api.set_velocity(0.3, 0.0, duration=5.0) is None
    assert rig.runner.link(0.0, rig.t) is True
    rig.t += 0.6
    # The loop was held up 0.3 s: the frames that came meanwhile are not read yet.
    assert rig.runner.link(0.6, rig.t, late=0.3) is True
    assert rig.motion.watchdog.active is not None
    assert rig.runner.count == {}
    assert rig.runner.link(0.6, rig.t, late=0.0) is False  # on time and still silent
    assert rig.runner.count == {"link": 1}
