"""Running a goal on a device: its plan (`goal`) stepped on each odometry sample, its
velocities offered to the motion core as a source of kind ``"goal"``.

Every way a goal ends leaves the robot stopped, and nothing of it acts afterwards (its
source is closed before the call returns or raises):

* within tolerance: a zero, then the pose once the robot is at rest (`MoveResult`);
* the awaiting task cancelled: a zero written at once, then ``CancelledError``;
* its timeout: a zero, then `MoveTimeoutError` (its ``result`` says where it got);
* a block (an e-stop, a bumper, a driver fault, a lost link, no odometry):
  `MotionBlockedError` (the block already stopped the robot);
* another source of higher priority, a stop from any source, or a newer goal:
  `MovePreemptedError` (whoever took over decides what the robot does).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Final, Protocol

import anyio

from ...errors import MotionBlockedError, MovePreemptedError, MoveTimeoutError, NotConnectedError
from ..validation import check_real
from .goal import DEFAULT_ANGULAR, DEFAULT_LINEAR, Line, MoveEnd, MoveResult, Plan, Profile, Turn
from .goal import go_to as go_to_plan

if TYPE_CHECKING:
    from ..dispatch import Subscription
    from ..odometry import Odometry
    from .drive import Motion, MotionSource
    from .watchdog import MotionLimits

__all__ = [
    "DEFAULT_ANGLE_TOLERANCE",
    "DEFAULT_TOLERANCE",
    "ODOMETRY_SILENCE",
    "Goals",
]

#: Default tolerances: 1 cm and 1°.
DEFAULT_TOLERANCE: Final = 0.01
DEFAULT_ANGLE_TOLERANCE: Final = math.radians(1.0)
#: No odometry sample for this long ends a goal as blocked (``NO_ODOMETRY``).
ODOMETRY_SILENCE: Final = 0.5
#: After the last zero, how long a finished goal waits for the robot to be at rest
#: (|v| < 1 mm/s and |w| < 0.001 rad/s) before it reports the pose.
SETTLE: Final = 0.5


class _Device(Protocol):
    @property
    def motion(self) -> Motion: ...
    @property
    def limits(self) -> MotionLimits: ...
    def odometry(self) -> Subscription[Odometry]: ...


def _profile(
    base: Profile,
    speed: float | None,
    accel: float | None,
    decel: float | None,
    limit: float | None,
    what: str,
) -> Profile:
    """``base`` with the call's speed and the device's limits (each honoured)."""
    cruise = base.speed if speed is None else check_real(speed, what, low=0, low_open=True)
    if limit is not None:
        cruise = min(cruise, limit)
    up = base.acceleration if accel is None else min(base.acceleration, accel)
    down = base.deceleration if decel is None else min(base.deceleration, decel)
    return Profile(cruise, up, down, min(base.creep, cruise), base.lag)


class Goals:
    """A device's goals (``robot.drive_distance``, ``robot.rotate``, ``robot.go_to``).

    Args:
        device: The device: its motion core, limits and odometry stream.
        clock: Monotonic clock, for durations and timeouts' reports.
    """

    def __init__(self, device: _Device, *, clock: Callable[[], float] = time.monotonic) -> None:
        self._device = device
        self._clock = clock

    # --- the calls -------------------------------------------------------------------------

    def _profiles(self, speed: float | None, rate: float | None) -> tuple[Profile, Profile]:
        limits = self._device.limits
        linear = _profile(
            DEFAULT_LINEAR,
            speed,
            limits.linear_acceleration,
            limits.linear_deceleration or limits.linear_acceleration,
            limits.max_linear,
            "speed",
        )
        angular = _profile(
            DEFAULT_ANGULAR,
            rate,
            limits.angular_acceleration,
            limits.angular_deceleration or limits.angular_acceleration,
            limits.max_angular,
            "rate",
        )
        return linear, angular

    async def drive_distance(
        self,
        distance: float,
        speed: float | None,
        tolerance: float | None,
        timeout: float | None,
        *,
        kind: str = "goal",
    ) -> MoveResult:
        distance = check_real(distance, "distance", unit="m")
        linear, angular = self._profiles(speed, None)
        tol = _tolerance(tolerance, DEFAULT_TOLERANCE, "m")
        timeout = _timeout(timeout)

        def plan(first: Odometry) -> Plan:
            start = (first.x, first.y)
            return Line(start, first.heading, distance, linear, angular, tol)

        return await self._run("drive_distance", plan, timeout, kind)

    async def rotate(
        self,
        angle: float,
        rate: float | None,
        tolerance: float | None,
        timeout: float | None,
        *,
        kind: str = "goal",
    ) -> MoveResult:
        angle = check_real(angle, "angle", unit="rad")
        _, angular = self._profiles(None, rate)
        tol = _tolerance(tolerance, DEFAULT_ANGLE_TOLERANCE, "rad")
        timeout = _timeout(timeout)
        plan = lambda _: Turn(angular, tol, angle=angle)  # noqa: E731
        return await self._run("rotate", plan, timeout, kind)

    async def go_to(
        self,
        x: float,
        y: float,
        heading: float | None,
        speed: float | None,
        tolerance: float | None,
        timeout: float | None,
        *,
        kind: str = "goal",
    ) -> MoveResult:
        x, y = check_real(x, "x", unit="m"), check_real(y, "y", unit="m")
        if heading is not None:
            heading = check_real(heading, "heading", unit="rad")
        linear, angular = self._profiles(speed, None)
        tol = _tolerance(tolerance, DEFAULT_TOLERANCE, "m")
        timeout = _timeout(timeout)
        plan = go_to_plan(x, y, heading, linear, angular, tol, DEFAULT_ANGLE_TOLERANCE)
        return await self._run("go_to", lambda _: plan, timeout, kind)

    # --- running one -----------------------------------------------------------------------

    async def _run(
        self, name: str, make: Callable[[Odometry], Plan], timeout: float | None, kind: str = "goal"
    ) -> MoveResult:
        motion = self._device.motion
        motion.check_open()
        if motion.blocks:
            names = ", ".join(motion.blocks)
            raise MotionBlockedError(f"{name} refused: blocked by {names}", motion.blocks)
        state = _State(self._clock, motion.arbiter.epoch)
        label = name if kind == "goal" else f"{kind} {name}"
        source = motion.source(label, kind=kind, streaming=False)
        try:
            with anyio.move_on_after(math.inf if timeout is None else timeout) as scope:
                await self._drive(source, make, state)
            if scope.cancelled_caught:
                source.close()  # the zero now, if it still drives
                result = state.result("timeout")
                raise MoveTimeoutError(
                    f"{name} did not finish in {timeout:g} s ({_left(name, result)})", result
                )
            if source.driving:
                source.stop()
            await self._settle(state)
            return state.result("done")
        finally:
            source.close()  # cancelled: the zero goes out at once; it never acts again

    async def _drive(
        self, source: MotionSource, make: Callable[[Odometry], Plan], state: _State
    ) -> None:
        motion = self._device.motion
        arbiter = motion.arbiter
        plan: Plan | None = None
        take_over = False
        async with self._device.odometry() as samples:
            while True:
                with anyio.move_on_after(ODOMETRY_SILENCE):
                    try:
                        pose = await samples.__anext__()
                    except StopAsyncIteration:
                        raise NotConnectedError("the device was closed during the goal") from None
                    state.pose = pose
                    # A stop from any source, or a block that began, since the call
                    # ends it, whether or not it held the lease yet.
                    why = source.source.ended_by
                    if why is None and arbiter.epoch != state.epoch:
                        why = "stopped"
                    if why is not None:
                        raise state.ended(why, motion.blocks)
                    if plan is None:
                        plan = state.plan = make(pose)
                        # A newer goal of the same kind takes over from an older one.
                        holder = arbiter.holder
                        take_over = holder is not None and holder.kind == source.source.kind
                    command = plan.step(pose)
                    if command is None:
                        return
                    refusal = source.set_velocity(*command, take_over=take_over)
                    take_over = False
                    if refusal is not None:
                        blocked = refusal.reason == "blocked"
                        raise state.ended(refusal.detail, refusal.blocks if blocked else ())
                    continue
                why = source.source.ended_by
                if why is not None or arbiter.epoch != state.epoch:
                    raise state.ended(why or "stopped", motion.blocks)
                raise MotionBlockedError(
                    f"goal ended: no odometry for {ODOMETRY_SILENCE:g} s", ("NO_ODOMETRY",)
                )

    async def _settle(self, state: _State) -> None:
        """Wait (at most `SETTLE`) for a sample at rest, the pose reported."""
        with anyio.move_on_after(SETTLE):
            async with self._device.odometry() as samples:
                async for pose in samples:
                    state.pose = pose
                    if abs(pose.linear) < 1e-3 and abs(pose.angular) < 1e-3:
                        break


class _State:
    """What a running goal has seen."""

    __slots__ = ("began", "clock", "epoch", "plan", "pose")

    def __init__(self, clock: Callable[[], float], epoch: int) -> None:
        self.clock = clock
        self.began = clock()
        #: The arbiter's epoch when it began (see `Arbiter.epoch`).
        self.epoch = epoch
        self.plan: Plan | None = None
        self.pose: Odometry | None = None

    def result(self, ended: MoveEnd) -> MoveResult:
        pose, duration = self.pose, self.clock() - self.began
        if self.plan is None or pose is None:
            return MoveResult(pose, math.nan, duration, ended, math.nan)
        error, heading = self.plan.error(pose)
        return MoveResult(pose, error, duration, ended, heading)

    def ended(self, why: str, blocks: tuple[str, ...] = ()) -> Exception:
        """The error for a goal ended by ``why``: a block (``blocks``, what blocks
        motion now, wins over a stop that came with it), or another source."""
        if not blocks and why.startswith("blocked by "):
            blocks = tuple(why.removeprefix("blocked by ").split(", "))
        if blocks:
            return MotionBlockedError(f"goal ended: blocked by {', '.join(blocks)}", blocks)
        return MovePreemptedError(f"goal ended: {why}", self.result("preempted"))


def _left(name: str, result: MoveResult) -> str:
    if name == "rotate":
        return f"{math.degrees(result.error):.1f}° left"
    return f"{result.error * 100:.1f} cm left"


def _tolerance(value: float | None, default: float, unit: str) -> float:
    if value is None:
        return default
    return check_real(value, "tolerance", low=0, low_open=True, unit=unit)


def _timeout(value: float | None) -> float | None:
    if value is None:
        return None
    return check_real(value, "timeout", low=0, low_open=True, unit="s")
