"""``chassis-sdk move``, ``turn`` and ``goto``: a goal (drive a distance, turn an
angle, go to a point of the odometry frame), closed on odometry through the motion
core, with a progress line; Ctrl-C stops the robot at once. A device whose motion is
blocked is refused before anything is written (exit 4)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Awaitable, Callable, Sequence
from typing import TYPE_CHECKING, Any

import anyio

from ..core.device import Device
from ..core.motion.goal import MoveResult
from ..core.odometry import Odometry, wrap_angle
from ..devices import DeviceProfile, profile
from ..errors import MotionBlockedError
from .arguments import (
    check_record,
    device_arg,
    finite,
    limit_args,
    port_args,
    positive,
    record_arg,
    require_port,
)
from .common import first, first_frame, out, progress_line
from .profile import device_options

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "move"]

#: A goal's default time limit on the command line (s).
DEFAULT_TIMEOUT = 60.0


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``move``, ``turn`` and ``goto``."""
    common = "Closed on odometry, within --max-linear/--max-angular; Ctrl-C stops at once."
    p = sub.add_parser(
        "move",
        help="drive a distance straight (metres, negative: backwards), then stop",
        description=f"Drive METRES straight ahead (negative: backwards), then stop. {common}",
    )
    _common(p, names)
    p.add_argument("metres", type=finite("metres"), help="how far (m)")
    p.add_argument("--speed", type=positive("speed"), help="m/s (default 0.3, within limits)")
    p.add_argument("--tolerance", type=positive("tolerance"), help="m (default 0.01)")
    p.set_defaults(func=_start_move)

    p = sub.add_parser(
        "turn",
        help="turn in place by an angle (degrees, counter-clockwise positive)",
        description=f"Turn in place by DEGREES (counter-clockwise positive). {common}",
    )
    _common(p, names)
    p.add_argument("degrees", type=finite("degrees"), help="how far (°)")
    p.add_argument("--rate", type=positive("rate"), help="°/s (default 45, within limits)")
    p.add_argument("--tolerance", type=positive("tolerance"), help="° (default 1)")
    p.set_defaults(func=_start_turn)

    p = sub.add_parser(
        "goto",
        help="go to a point (and heading) of the odometry frame",
        description="Face the point X Y (metres, the odometry frame: where the robot "
        "was when it connected), drive to it, then turn to HEADING (degrees) if given. " + common,
    )
    _common(p, names)
    p.add_argument("x", type=finite("x"), help="m forward of the start")
    p.add_argument("y", type=finite("y"), help="m left of the start")
    p.add_argument("heading", type=finite("heading"), nargs="?", help="° (optional)")
    p.add_argument("--speed", type=positive("speed"), help="m/s (default 0.3, within limits)")
    p.add_argument("--tolerance", type=positive("tolerance"), help="m (default 0.01)")
    p.set_defaults(func=_start_goto)


def _common(p: argparse.ArgumentParser, names: Sequence[str]) -> None:
    port_args(p)
    device_arg(p, names)
    limit_args(p, "the goal's speeds")
    p.add_argument(
        "--timeout",
        type=positive("timeout"),
        default=DEFAULT_TIMEOUT,
        help="seconds before it gives up and stops; default %(default)s",
    )
    record_arg(p)


# One function per command (as every command has: none falls through to another).
def _start_move(args: argparse.Namespace) -> Job:
    args.goal = "move"
    check_record(args, "move")
    return move(profile(args.device), require_port(args), args)


def _start_turn(args: argparse.Namespace) -> Job:
    args.goal = "turn"
    check_record(args, "turn")
    return move(profile(args.device), require_port(args), args)


def _start_goto(args: argparse.Namespace) -> Job:
    args.goal = "goto"
    check_record(args, "goto")
    return move(profile(args.device), require_port(args), args)


def _call(
    args: argparse.Namespace,
) -> tuple[Callable[[Device[Any, Any]], Awaitable[MoveResult]], str]:
    """The goal to await on a device, and what it is, from the arguments."""
    timeout, goal = args.timeout, args.goal
    if goal == "move":
        return (
            lambda dev: dev.drive_distance(
                args.metres, args.speed, tolerance=args.tolerance, timeout=timeout
            ),
            f"{args.metres:g} m",
        )
    if goal == "turn":
        rate = None if args.rate is None else math.radians(args.rate)
        tol = None if args.tolerance is None else math.radians(args.tolerance)
        angle = math.radians(args.degrees)
        return (
            lambda dev: dev.rotate(angle, rate, tolerance=tol, timeout=timeout),
            f"{args.degrees:g}°",
        )
    heading = None if args.heading is None else math.radians(args.heading)
    where = f"({args.x:g}, {args.y:g})"
    if heading is not None:
        where += f" heading {args.heading:g}°"
    return (
        lambda dev: dev.go_to(
            args.x, args.y, heading, speed=args.speed, tolerance=args.tolerance, timeout=timeout
        ),
        where,
    )


def _progress(goal: str, start: Odometry, args: argparse.Namespace) -> Callable[[Odometry], str]:
    """How far a goal has got, as one line, from each odometry sample."""
    if goal == "move":

        def moved(o: Odometry) -> str:
            along = (o.x - start.x) * math.cos(start.heading) + (o.y - start.y) * math.sin(
                start.heading
            )
            return f"{along:+.3f} of {args.metres:+.3f} m at {o.linear:+.2f} m/s"

        return moved
    if goal == "turn":
        turned = [0.0, start.heading]

        def turning(o: Odometry) -> str:
            turned[0] += wrap_angle(o.heading - turned[1])
            turned[1] = o.heading
            return f"{math.degrees(turned[0]):+.1f} of {args.degrees:+.1f}°"

        return turning

    def going(o: Odometry) -> str:
        return (
            f"{o.distance_to(args.x, args.y):.3f} m to go; at ({o.x:+.3f}, {o.y:+.3f}), "
            f"heading {math.degrees(o.heading):+.1f}°"
        )

    return going


async def move(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Run the goal ``args.goal`` (``move``, ``turn``, ``goto``) on ``device`` at
    ``port``, a progress line from odometry, and print how it ended.

    Raises:
        MotionBlockedError: Motion is blocked before it starts, or a block ends it.
        MoveTimeoutError, MovePreemptedError: It timed out, or another source took over.
    """
    call, what = _call(args)
    try:
        async with device.device(port, **device_options(args, record=args.record)) as dev:
            await first_frame(dev, 3.0, device.recognised_by)
            blocked = dev.motion_blocked()
            if blocked:
                raise MotionBlockedError(f"{args.goal} refused", blocked)
            result = await _run(dev, call, args, what)
    except anyio.get_cancelled_exc_class():
        out("interrupted; stopped")  # the goal's zero, then close()'s
        raise
    unit = "°" if args.goal == "turn" else " m"
    error = math.degrees(result.error) if args.goal == "turn" else result.error
    out(f"{args.goal} {what}: done in {result.duration:.1f} s, {error:+.3g}{unit} off")


async def _run(
    dev: Device[Any, Any],
    call: Callable[[Device[Any, Any]], Awaitable[MoveResult]],
    args: argparse.Namespace,
    what: str,
) -> MoveResult:
    async with dev.odometry() as odometry:
        start = await first(odometry, 3.0, "odometry")
        line = progress_line(f"{args.goal} {what}")
        tell = _progress(args.goal, start, args)
        result: MoveResult | None = None
        async with anyio.create_task_group() as tg:

            async def follow() -> None:
                async for sample in odometry:
                    line(tell(sample))

            tg.start_soon(follow)
            try:
                result = await call(dev)
            finally:
                tg.cancel_scope.cancel()
                line.done("")
    assert result is not None
    return result
