"""Motion limits: what is written is clamped and ramped towards the command; what was
asked stays the command; every kind of stop is immediate."""

from __future__ import annotations

import itertools
import math
import struct

import pytest

from chassis_sdk import Chassis, MotionLimits
from chassis_sdk.core.motion.watchdog import _ramp

from .support.standin import ChassisStandIn, Received, drive_frames


def velocities(frames: list[Received]) -> list[tuple[float, float]]:
    """(linear m/s, angular rad/s) of each mode-0 drive frame, in order."""
    out = []
    for f in drive_frames(frames):
        mode, vx, wz = struct.unpack("<Hhf", f.payload)
        assert mode == 0
        out.append((vx / 1000, wz))
    return out


# --- the ramp rule --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("current", "goal", "accel", "decel", "expected"),
    [
        pytest.param(0.0, 1.0, 2.0, 4.0, 0.1, id="from rest: acceleration"),
        pytest.param(0.5, 1.0, 2.0, 4.0, 0.6, id="speeding up"),
        pytest.param(1.0, 0.0, 2.0, 4.0, 0.8, id="slowing: deceleration"),
        pytest.param(-1.0, 0.0, 2.0, 4.0, -0.8, id="slowing backwards"),
        pytest.param(0.1, -1.0, 2.0, 4.0, 0.0, id="reversing stops at zero first"),
        pytest.param(0.95, 1.0, 2.0, 4.0, 1.0, id="last step lands on the goal"),
        pytest.param(0.0, 1.0, None, None, 1.0, id="no limit: jump"),
        pytest.param(1.0, 0.2, 2.0, None, 0.2, id="no deceleration limit"),
    ],
)
def test_ramp_step(
    current: float, goal: float, accel: float | None, decel: float | None, expected: float
) -> None:
    assert _ramp(current, goal, accel, decel, 0.05) == pytest.approx(expected)


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"max_linear": 0}, ValueError),
        ({"max_angular": -1.0}, ValueError),
        ({"linear_acceleration": math.nan}, ValueError),
        ({"angular_deceleration": math.inf}, ValueError),
        ({"max_linear": True}, TypeError),
        ({"linear_deceleration": "1"}, TypeError),
    ],
    ids=["zero", "negative", "nan", "inf", "bool", "string"],
)
def test_bad_limits_raise_value_or_type_error(
    kwargs: dict[str, object], error: type[Exception]
) -> None:
    # A bad value is a ValueError, a wrong type a TypeError (as the standard library).
    with pytest.raises(error, match=next(iter(kwargs))) as info:
        MotionLimits(**kwargs)  # type: ignore[arg-type]
    assert type(info.value) is error


def test_limits_must_be_motion_limits() -> None:
    with pytest.raises(TypeError, match="MotionLimits"):
        Chassis("/dev/null", limits={"max_linear": 1.0})  # type: ignore[arg-type]


# --- on the wire, against the independent stand-in ------------------------------------------


@pytest.mark.integration
@pytest.mark.timing
async def test_ramp_up_holds_the_acceleration_and_stop_is_immediate() -> None:
    limits = MotionLimits(linear_acceleration=2.0, angular_acceleration=4.0)
    async with (
        ChassisStandIn(noise=False) as dev,
        Chassis(dev.port, limits=limits, command_timeout=None) as robot,
    ):
        await robot.set_velocity(0.5, 1.0)
        assert robot.commanded_velocity == (0.5, 1.0)  # the command is what was asked
        await dev.wait_for(lambda fs: (0.5, 1.0) in velocities(fs))
        ramp = velocities(dev.frames)
        times = [f.time for f in drive_frames(dev.frames)]
        assert ramp[0] == pytest.approx((0.1, 0.2))  # one period's worth from rest
        for (v0, w0), (v1, w1), t0, t1 in zip(ramp, ramp[1:], times, times[1:], strict=False):
            dt = min(t1 - t0, 0.05) + 0.002  # the watchdog never steps more than a period
            assert 0 <= v1 - v0 <= 2.0 * dt + 0.001
            assert 0 <= w1 - w0 <= 4.0 * dt + 1e-6
        assert len(ramp) >= 5  # 0.5 m/s at 2 m/s² takes 0.25 s: five periods
        assert robot.written_velocity == pytest.approx((0.5, 1.0))
        n = len(ramp)
        await robot.stop()
        await dev.wait_for(lambda fs: len(drive_frames(fs)) > n)
        assert velocities(dev.frames)[n] == (0.0, 0.0)  # no ramp down: zero at once
        assert robot.commanded_velocity is None


@pytest.mark.integration
async def test_a_lower_command_ramps_down_with_the_deceleration() -> None:
    limits = MotionLimits(linear_acceleration=10.0, linear_deceleration=2.0)
    async with (
        ChassisStandIn(noise=False) as dev,
        Chassis(dev.port, limits=limits, command_timeout=None) as robot,
    ):
        await robot.set_velocity(0.5, 0.0)
        await dev.wait_for(lambda fs: (0.5, 0.0) in velocities(fs))
        n = len(velocities(dev.frames))
        await robot.set_velocity(0.0, 0.0)  # a command, not a stop: ramped
        await dev.wait_for(lambda fs: velocities(fs)[-1] == (0.0, 0.0))
        down = [v for v, _ in velocities(dev.frames)[n - 1 :]]
        # Each write steps down by at most 2 m/s² x the time since the last (<= 50 ms).
        assert all(0 <= a - b <= 0.1 + 1e-3 for a, b in itertools.pairwise(down))
        assert len(down) >= 6  # 0.5 m/s at 2 m/s²: at least five steps after the top


@pytest.mark.integration
async def test_max_speeds_clamp_what_is_written_not_what_was_asked() -> None:
    limits = MotionLimits(max_linear=0.3, max_angular=0.5)
    async with (
        ChassisStandIn(noise=False) as dev,
        Chassis(dev.port, limits=limits) as robot,
    ):
        await robot.set_velocity(1.0, -2.0)
        await dev.wait_for(lambda fs: len(drive_frames(fs)) >= 1)
        assert velocities(dev.frames)[0] == pytest.approx((0.3, -0.5))
        assert robot.commanded_velocity == (1.0, -2.0)
        robot.limits = None  # limits can be changed on the fly
        await robot.set_velocity(1.0, -2.0)
        await dev.wait_for(lambda fs: len(drive_frames(fs)) >= 2)
        assert velocities(dev.frames)[-1] == pytest.approx((1.0, -2.0))


@pytest.mark.integration
async def test_deadman_and_duration_stop_at_once_despite_ramps() -> None:
    limits = MotionLimits(linear_acceleration=1.0, linear_deceleration=0.1)
    async with (
        ChassisStandIn(noise=False) as dev,
        Chassis(dev.port, limits=limits, command_timeout=0.3) as robot,
    ):
        await robot.set_velocity(0.2, 0.0)
        await dev.wait_for(lambda fs: velocities(fs)[-1:] == [(0.0, 0.0)])
        seen = [v for v, _ in velocities(dev.frames)]
        assert max(seen) > 0.1
        assert seen[-2] > 0.1  # the deadman wrote zero straight from speed
        await robot.set_velocity(0.2, 0.0, duration=0.2)
        await dev.wait_for(lambda fs: velocities(fs)[-1:] == [(0.0, 0.0)] and len(fs) > len(seen))
        assert robot.stats.command_expiries == 2


@pytest.mark.integration
async def test_wheel_mode_ramps_each_side_with_the_linear_limits() -> None:
    limits = MotionLimits(max_linear=0.4, linear_acceleration=2.0)
    async with (
        ChassisStandIn(noise=False) as dev,
        Chassis(dev.port, limits=limits, command_timeout=None) as robot,
    ):
        await robot.set_wheel_speeds(-1.0, 0.2)
        await dev.wait_for(lambda fs: len(drive_frames(fs)) >= 6)
        sides = [struct.unpack("<Hhh", f.payload[:6])[1:] for f in drive_frames(dev.frames)]
        assert sides[0] == (-100, 100)
        assert sides[-1] == (-400, 200)  # clamped to max_linear, each side ramped


@pytest.mark.integration
async def test_the_board_ramps_through_the_same_watchdog() -> None:
    from chassis_sdk import Board

    from .support.standin import BoardStandIn

    limits = MotionLimits(linear_acceleration=1.0, max_angular=0.5)
    async with (
        BoardStandIn(noise=False) as dev,
        Board(dev.port, limits=limits, command_timeout=None) as board,
    ):
        await board.set_velocity(0.2, 2.0)
        await dev.wait_for(
            lambda fs: any(f.kind == 0x22 and f.payload[:2] == b"\xc8\x00" for f in fs)
        )
        await board.stop()
        await dev.wait_for(lambda fs: fs[-1].kind == 0x22 and fs[-1].payload == bytes(4))
    sent = [struct.unpack("<hh", f.payload) for f in dev.frames if f.kind == 0x22]
    # 1 m/s² at the 50 ms period: the first write is one period's worth (50 mm/s); each
    # later one moves by the time since the last write, never more than one period's
    # worth (a late write does not catch up), so steps are at most 50 (+1 rounding) and
    # the ramp climbs to the target. The exact steps depend on the timer (a write 3 ms
    # late makes the next step 47); the arithmetic itself is test_ramp_step's.
    ramp = [v for v, _ in sent[: sent.index((200, 500)) + 1]]
    assert ramp[0] == 50
    steps = [b - a for a, b in itertools.pairwise(ramp)]
    assert steps
    assert all(0 < s <= 51 for s in steps), ramp
    stop = sent.index((0, 0))  # stop(), then the zero written on leaving the block
    assert all(w == 500 for _, w in sent[:stop])  # clamped; no angular ramp was set
    assert sent[stop - 1] == (200, 500)  # full speed right before: the stop is not ramped
    assert set(sent[stop:]) == {(0, 0)}
