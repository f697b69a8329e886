"""Goals as plans, sans-IO: each plan driven on a model robot (an injected clock: the
samples' timestamps; a command acts one period late, the wheels at most 1.5 m/s²), and
what it commands. The same goals on the simulators, through a real transport, are in
``test_goals.py``."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import pytest

from chassis_sdk.core.motion import Arbiter
from chassis_sdk.core.motion.goal import (
    DEFAULT_ANGULAR,
    DEFAULT_LINEAR,
    Line,
    Plan,
    Profile,
    Turn,
    go_to,
    speed_for,
)
from chassis_sdk.core.odometry import wrap_angle

pytestmark = pytest.mark.codec  # pure: no I/O, an injected clock

PERIOD = 0.02  # the telemetry period: a sample each
TRACK = 0.5


@dataclass
class Sample:
    x: float
    y: float
    heading: float
    linear: float
    angular: float
    timestamp: float


@dataclass
class Robot:
    """A differential base: commands act one period late, each wheel's speed changes at
    most ``accel`` m/s², the pose integrates the wheels' speeds."""

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    v: float = 0.0
    w: float = 0.0
    t: float = 0.0
    accel: float = 1.5

    def step(self, command: tuple[float, float]) -> None:
        cv, cw = command
        dv = self.accel * PERIOD
        left, right = self.v - self.w * TRACK / 2, self.v + self.w * TRACK / 2
        want_l, want_r = cv - cw * TRACK / 2, cv + cw * TRACK / 2
        left += max(-dv, min(dv, want_l - left))
        right += max(-dv, min(dv, want_r - right))
        self.v, self.w = (left + right) / 2, (right - left) / TRACK
        mid = self.heading + self.w * PERIOD / 2
        self.x += self.v * PERIOD * math.cos(mid)
        self.y += self.v * PERIOD * math.sin(mid)
        self.heading = wrap_angle(self.heading + self.w * PERIOD)
        self.t += PERIOD

    def sample(self) -> Sample:
        return Sample(self.x, self.y, self.heading, self.v, self.w, self.t)


def run(plan: Plan, robot: Robot, limit: float = 60.0) -> tuple[list[tuple[float, float]], Sample]:
    """Step ``plan`` on ``robot`` until it is done and the robot at rest: the commands
    it gave, and the sample at rest."""
    commands: list[tuple[float, float]] = []
    pending = (0.0, 0.0)
    while robot.t < limit:
        robot.step(pending)  # what was commanded a period ago acts now
        command = plan.step(robot.sample())
        if command is None:
            break
        commands.append(command)
        pending = command
    else:
        raise AssertionError(f"not done in {limit} s")
    while abs(robot.v) > 1e-9 or abs(robot.w) > 1e-9:
        robot.step((0.0, 0.0))
    return commands, robot.sample()


def sign_changes(values: list[float]) -> int:
    signs = [math.copysign(1, v) for v in values if abs(v) > 1e-9]
    return sum(1 for a, b in itertools.pairwise(signs) if a != b)


@pytest.mark.parametrize(
    ("remaining", "previous", "dt", "expected"),
    [
        (1.0, 0.0, 0.02, 0.02),  # from rest: the creep (the ramp's first step is 0.01)
        (1.0, 0.1, 0.02, 0.11),  # ramping up at 0.5 m/s²
        (1.0, 0.3, 0.02, 0.3),  # cruising
        (0.04, 0.3, 0.02, math.sqrt(2 * 0.5 * (0.04 - 0.3 * 0.04))),  # braking, lag taken off
        (0.001, 0.05, 0.02, 0.02),  # the last millimetres at the creep
        (-1.0, 0.3, 0.02, -0.02),  # the other way: from rest, not from +0.3
    ],
)
def test_the_speed_profile(remaining: float, previous: float, dt: float, expected: float) -> None:
    assert speed_for(remaining, previous, DEFAULT_LINEAR, dt) == pytest.approx(expected)


LINE = (DEFAULT_LINEAR, DEFAULT_ANGULAR)


def line(distance: float, tolerance: float = 0.01) -> Line:
    return Line((0.0, 0.0), 0.0, distance, *LINE, tolerance)


@pytest.mark.parametrize(
    ("what", "plan", "robot", "tolerance", "angle_tolerance"),
    [
        ("1 m", lambda: line(1.0), Robot(), 0.01, None),
        ("backwards 0.5 m", lambda: line(-0.5), Robot(), 0.01, None),
        ("3 cm: never reaches cruise", lambda: line(0.03), Robot(), 0.01, None),
        ("2 m to 1 mm", lambda: line(2.0, 0.001), Robot(), 0.001, None),
        ("1 m off the line's heading by 5°", lambda: line(1.0), Robot(heading=0.087), 0.01, None),
        (
            "90°",
            lambda: Turn(DEFAULT_ANGULAR, math.radians(1), angle=math.pi / 2),
            Robot(),
            None,
            1,
        ),
        (
            "-450°",
            lambda: Turn(DEFAULT_ANGULAR, math.radians(1), angle=-2.5 * math.pi),
            Robot(),
            None,
            1,
        ),
        (
            "to heading 170° across ±180°",
            lambda: Turn(DEFAULT_ANGULAR, math.radians(1), heading=math.radians(170)),
            Robot(heading=math.radians(-170)),
            None,
            1,
        ),
        (
            "go to (1, 1), heading 0",
            lambda: go_to(1, 1, 0.0, *LINE, 0.01, math.radians(1)),
            Robot(),
            0.01,
            1,
        ),
        (
            "go to (-1, 0.5), behind",
            lambda: go_to(-1, 0.5, None, *LINE, 0.01, math.radians(1)),
            Robot(),
            0.01,
            None,
        ),
        (
            "go to where it is: nothing",
            lambda: go_to(0, 0, None, *LINE, 0.01, math.radians(1)),
            Robot(),
            0.01,
            None,
        ),
    ],
)
def test_a_plan_ends_within_tolerance_without_oscillating(
    what: str, plan: Any, robot: Robot, tolerance: float | None, angle_tolerance: float | None
) -> None:
    p = plan()
    commands, rest = run(p, robot)
    error, heading_error = p.error(rest)
    if tolerance is not None:
        assert abs(error) <= tolerance, what
    if angle_tolerance is not None:
        assert abs(math.degrees(heading_error if tolerance else error)) <= angle_tolerance, what
    linear = [c[0] for c in commands]
    angular = [c[1] for c in commands]
    assert max((abs(v) for v in linear), default=0.0) <= DEFAULT_LINEAR.speed + 1e-9
    assert max((abs(w) for w in angular), default=0.0) <= DEFAULT_ANGULAR.speed + 1e-9
    # No oscillation: the drive never reverses (a go-to's turn and line are phases).
    assert sign_changes(linear) == 0, what
    if not isinstance(p, Line):
        assert sign_changes([w for v, w in commands if v == 0.0]) <= 1, what
    # The ramps: speeding up at most the acceleration a period (the creep is the floor).
    for before, after in itertools.pairwise(linear):
        if abs(after) > abs(before) and abs(after) > DEFAULT_LINEAR.creep:
            assert abs(after) - abs(before) <= DEFAULT_LINEAR.acceleration * PERIOD + 1e-9


def test_a_plan_starts_from_its_first_sample_wherever_that_is() -> None:
    robot = Robot(x=2.0, y=-1.0, heading=math.pi / 2)
    plan = Line((2.0, -1.0), math.pi / 2, 0.5, *LINE, 0.01)
    _, rest = run(plan, robot)
    assert rest.x == pytest.approx(2.0, abs=0.01)
    assert rest.y == pytest.approx(-0.5, abs=0.01)


def test_a_slow_profile_is_honoured() -> None:
    slow = Profile(0.1, 0.2, 0.2, 0.01)
    commands, _ = run(Line((0, 0), 0, 0.5, slow, DEFAULT_ANGULAR, 0.01), Robot())
    assert max(c[0] for c in commands) == pytest.approx(0.1)
    assert commands[1][0] - commands[0][0] <= 0.2 * PERIOD + 1e-9


# The arbiter tells a source why its lease ended: a goal reads it and ends at once.
@pytest.mark.parametrize(
    ("event", "ended_by"),
    [
        (lambda a, goal, other: a.stop(other), "stopped by api"),
        (lambda a, goal, other: a.stop(), "stopped"),
        (lambda a, goal, other: a.granted(other, math.inf), "taken by api"),
        (
            lambda a, goal, other: a.set_blocks("device", ["FRONT_BUMPER"]),
            "blocked by FRONT_BUMPER",
        ),
        (lambda a, goal, other: a.stop(goal), None),  # its own stop
        (lambda a, goal, other: a.granted(goal, math.inf), None),  # its own new command
        (lambda a, goal, other: a.set_blocks("device", []), None),  # nothing began
    ],
)
def test_a_lease_ended_by_another_says_why(event: Any, ended_by: str | None) -> None:
    t = [0.0]
    arbiter = Arbiter(clock=lambda: t[0])
    goal = arbiter.add("drive_distance", "goal", streaming=False)
    api = arbiter.add("api", "api", streaming=False)
    assert arbiter.velocity(goal, neutral=False) is True
    arbiter.granted(goal, 0.5)
    event(arbiter, goal, api)
    assert goal.ended_by == ended_by


def test_a_lease_that_lapsed_was_not_ended_by_anyone() -> None:
    t = [0.0]
    arbiter = Arbiter(clock=lambda: t[0])
    goal = arbiter.add("rotate", "goal", streaming=False)
    api = arbiter.add("api", "api", streaming=False)
    arbiter.granted(goal, 0.5)
    t[0] = 0.6
    arbiter.stop(api)
    assert goal.ended_by is None
