"""The velocity watchdog on a fake clock: its decisions (:meth:`VelocityWatchdog.due`
and :meth:`VelocityWatchdog.tick`, the step of its background loop) at exact times,
with every frame it writes recorded. No loop, no port, no sleep.

The interval (0.125 s) and the rates are powers of two, so every time and every ramp
step is exact in binary and the assertions compare with ``==``.
"""

from __future__ import annotations

import logging
import math

import pytest

from chassis_sdk.core.motion import MotionLimits, VelocityWatchdog
from chassis_sdk.errors import NotConnectedError

INTERVAL = 0.125
TIMEOUT = 0.5


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Recorder:
    """The watchdog's write callback: every frame with its expiry."""

    def __init__(self) -> None:
        self.frames: list[tuple[str, float]] = []
        self.connected = True

    def __call__(self, frame: bytes, expires: float) -> None:
        if not self.connected:
            raise NotConnectedError("no link")
        self.frames.append((frame.decode(), expires))


def build(a: float, b: float) -> bytes:
    return f"V {a!r} {b!r}".encode()


def zero() -> bytes:
    return b"ZERO"


def make(
    *, command_timeout: float | None = TIMEOUT, limits: MotionLimits | None = None
) -> tuple[VelocityWatchdog, FakeClock, Recorder]:
    clock, rec = FakeClock(), Recorder()
    wd = VelocityWatchdog(
        rec,
        interval=INTERVAL,
        command_timeout=command_timeout,
        logger=logging.getLogger("test_watchdog_clock"),
        limits=limits,
        clock=clock,
    )
    return wd, clock, rec


def command(
    wd: VelocityWatchdog, target: tuple[float, float], duration: float | None = None
) -> None:
    wd.command(target, build, zero, duration, "test")


def run_until(wd: VelocityWatchdog, clock: FakeClock, end: float) -> None:
    """What ``run()`` does until ``end``: tick at each time something is due."""
    while (due := wd.due()) is not None and due <= end:
        clock.now = due
        wd.tick(due)
    clock.now = end


def test_the_clock_is_injectable_and_a_command_is_written_at_once() -> None:
    wd, clock, rec = make()
    clock.now = 3.0
    command(wd, (0.5, 0.25))
    assert rec.frames == [("V 0.5 0.25", 3.5)]  # expires command_timeout after now
    assert wd.active is not None
    assert wd.active.deadline == 3.5
    assert wd.written == (0.5, 0.25)
    assert wd.due() == 3.125
    assert wd.resends == 0


def test_without_duration_it_expires_exactly_command_timeout_after_the_last_call() -> None:
    wd, clock, rec = make()
    command(wd, (0.5, 0.25))
    clock.now = 0.25
    command(wd, (0.5, 0.25))  # called again: the deadman restarts from here
    rec.frames.clear()
    wd.tick(0.374)  # nothing due yet (the next resend is at 0.375)
    assert rec.frames == []
    run_until(wd, clock, 0.7499)
    assert rec.frames == [("V 0.5 0.25", 0.75)] * 3  # 0.375, 0.5, 0.625
    assert wd.due() == 0.75
    wd.tick(0.7499)
    assert len(rec.frames) == 3
    wd.tick(0.75)
    assert rec.frames[3:] == [("ZERO", math.inf)]
    assert wd.active is None
    assert wd.due() is None
    assert wd.expiries == 1
    assert wd.resends == 3
    assert wd.written == (0.0, 0.0)


def test_one_zero_is_written_on_expiry_and_nothing_after() -> None:
    wd, clock, rec = make()
    command(wd, (0.5, 0.0))
    run_until(wd, clock, 10.0)
    assert [f for f, _ in rec.frames].count("ZERO") == 1
    assert rec.frames[-1] == ("ZERO", math.inf)
    count = len(rec.frames)
    wd.tick(20.0)
    assert len(rec.frames) == count
    assert wd.expiries == 1


def test_with_duration_it_holds_exactly_that_long_past_the_deadman() -> None:
    wd, clock, rec = make()
    command(wd, (0.5, 0.0), duration=1.0)  # twice the deadman
    run_until(wd, clock, 0.9999)
    # The first write, then a resend every interval up to 0.875: none is zero.
    assert rec.frames == [("V 0.5 0.0", 1.0)] * 8
    assert wd.active is not None
    wd.tick(1.0)
    assert rec.frames[8:] == [("ZERO", math.inf)]
    assert wd.active is None
    assert (wd.resends, wd.expiries) == (7, 1)


def test_a_duration_shorter_than_the_interval_expires_before_any_resend() -> None:
    wd, clock, rec = make()
    command(wd, (0.5, 0.0), duration=0.0625)
    assert wd.due() == 0.0625
    run_until(wd, clock, 1.0)
    assert rec.frames == [("V 0.5 0.0", 0.0625), ("ZERO", math.inf)]
    assert wd.resends == 0


def test_resends_follow_an_absolute_schedule_and_skip_missed_slots() -> None:
    wd, _, rec = make(command_timeout=None)
    command(wd, (0.5, 0.0))
    assert rec.frames == [("V 0.5 0.0", math.inf)]  # held until stop()
    for t in (0.125, 0.25, 0.375):
        assert wd.due() == t
        wd.tick(t + 0.01)  # a little late: the schedule does not drift
    assert wd.due() == 0.5
    assert wd.resends == 3
    wd.tick(1.0)  # the loop was blocked past 0.5, 0.625, ... 1.0: one resend
    assert wd.resends == 4
    assert wd.due() == 1.125
    assert len(rec.frames) == 5
    assert wd.active is not None


def test_the_limits_clamp_what_is_written_not_what_was_asked() -> None:
    wd, clock, rec = make(limits=MotionLimits(max_linear=0.5, max_angular=1.0))
    command(wd, (2.0, -3.0))
    assert rec.frames == [("V 0.5 -1.0", TIMEOUT)]
    assert wd.written == (0.5, -1.0)
    assert wd.active is not None
    assert wd.active.target == (2.0, -3.0)
    run_until(wd, clock, 0.125)
    assert rec.frames[-1] == ("V 0.5 -1.0", TIMEOUT)


def test_in_wheel_mode_max_linear_caps_each_side() -> None:
    wd, _, rec = make(limits=MotionLimits(max_linear=0.5, max_angular=0.25))
    wd.command((0.75, -2.0), build, zero, None, "wheels", axes="wheels")
    assert rec.frames == [("V 0.5 -0.5", TIMEOUT)]


def test_a_ramp_advances_by_acceleration_times_the_time_since_the_last_write() -> None:
    wd, clock, rec = make(
        command_timeout=None,
        limits=MotionLimits(linear_acceleration=2.0, linear_deceleration=4.0),
    )
    command(wd, (1.0, 0.5))  # angular has no ramp: at once
    run_until(wd, clock, 0.5)
    assert [f for f, _ in rec.frames] == [
        "V 0.25 0.5",  # from rest: one interval's worth (2 m/s² × 0.125 s)
        "V 0.5 0.5",
        "V 0.75 0.5",
        "V 1.0 0.5",
        "V 1.0 0.5",
    ]
    rec.frames.clear()
    clock.now = 0.5625  # the application calls sooner: a shorter step
    command(wd, (0.0, 0.5))
    assert rec.frames == [("V 0.75 0.5", math.inf)]  # decelerating at 4 m/s² × 0.0625 s
    run_until(wd, clock, 0.8125)
    assert [f for f, _ in rec.frames] == ["V 0.75 0.5", "V 0.25 0.5", "V 0.0 0.5"]


def test_a_reversal_ramps_down_to_zero_first_then_up_the_other_way() -> None:
    wd, clock, rec = make(
        command_timeout=None,
        limits=MotionLimits(linear_acceleration=2.0, linear_deceleration=4.0),
    )
    command(wd, (0.25, 0.0))
    clock.now = 0.125
    command(wd, (-1.0, 0.0))  # a step of 0.5 towards -1 would cross zero: it stops there
    run_until(wd, clock, 0.375)
    assert [f for f, _ in rec.frames] == ["V 0.25 0.0", "V 0.0 0.0", "V -0.25 0.0", "V -0.5 0.0"]


def test_stop_writes_zero_at_once_never_ramped_and_clears() -> None:
    wd, clock, rec = make(limits=MotionLimits(linear_acceleration=2.0))
    command(wd, (1.0, 0.0))
    run_until(wd, clock, 0.25)
    assert wd.written == (0.75, 0.0)
    rec.frames.clear()
    wd.stop(zero)
    assert rec.frames == [("ZERO", math.inf)]
    assert wd.active is None
    assert wd.written == (0.0, 0.0)
    assert wd.due() is None
    wd.tick(5.0)
    assert rec.frames == [("ZERO", math.inf)]
    assert wd.expiries == 0
    clock.now = 5.0
    command(wd, (1.0, 0.0))  # from rest again
    assert rec.frames[-1] == ("V 0.25 0.0", 5.0 + TIMEOUT)


def test_clear_forgets_the_command_without_writing() -> None:
    wd, clock, rec = make()
    command(wd, (0.5, 0.0))
    wd.clear()
    assert wd.active is None
    assert wd.due() is None
    run_until(wd, clock, 5.0)
    assert rec.frames == [("V 0.5 0.0", TIMEOUT)]
    assert (wd.resends, wd.expiries) == (0, 0)


def test_a_command_without_a_link_changes_nothing() -> None:
    wd, _, rec = make()
    rec.connected = False
    with pytest.raises(NotConnectedError):
        command(wd, (0.5, 0.0))
    assert wd.active is None
    assert wd.written == (0.0, 0.0)
    assert wd.due() is None


def test_a_link_lost_between_resends_clears_the_command_for_good() -> None:
    wd, clock, rec = make()
    command(wd, (0.5, 0.0))
    rec.connected = False
    clock.now = 0.125
    wd.tick(0.125)
    assert wd.active is None
    assert wd.due() is None
    assert wd.resends == 1  # counted as attempted
    rec.connected = True
    run_until(wd, clock, 5.0)  # never resumed
    assert rec.frames == [("V 0.5 0.0", TIMEOUT)]
    assert wd.expiries == 0
