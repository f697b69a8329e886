"""``chassis-sdk calibrate PORT linear|angular``: measure the odometry's calibration
factors and write them to the profile's ``[calibration]`` table.

``linear --distance D`` drives straight ahead, slowly, until the odometry says ``D``
metres; the operator measures how far the robot really went (``--measured`` gives it on
the command line). ``angular --turns N`` turns in place until the odometry says ``N``
turns; the operator counts the real turns, or, with a gyro (``--imu``; a board's is
used by default), the gyro's integrated rate is the truth and nobody measures anything.

The factor in use (the profile's) is applied while driving, and the new one is that
factor corrected by measured over reported, so running a calibration again converges.
The drive is an ordinary command under the device's deadman and the limits: Ctrl-C, a
lost link or a crash stops the robot as everywhere else.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import anyio

from ..core.calibration import SCALE_RANGE, Calibration, combined_scale
from ..core.device import Device
from ..core.odometry import wrap_angle
from ..devices import DeviceProfile, profile
from ..devices.config import find_profile, load_profile, update_profile
from ..errors import ChassisError
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
from .common import first_frame, out, progress_line
from .profile import device_options

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["CalibrationRun", "add_parser", "calibrate", "drive_straight", "turn_in_place"]

#: Default speeds: slow, so the wheels grip and an operator can walk beside.
LINEAR_SPEED = 0.2  # m/s
ANGULAR_SPEED = 0.5  # rad/s
#: Seconds the robot has to show it moves before the run is called off.
MOVE_WITHIN = 2.0
#: Seconds without an odometry sample that end the run.
SILENCE = 1.0
#: Below these (m/s, rad/s) for STILL_FOR seconds, the robot has stopped.
STILL_LINEAR, STILL_ANGULAR, STILL_FOR = 0.005, 0.01, 0.3


@dataclass(frozen=True, slots=True)
class CalibrationRun:
    """What one calibration drive measured.

    Attributes:
        reported: What the (calibrated) odometry reported, from standstill to
            standstill: metres along the path (linear) or radians turned (angular).
        gyro: Radians the gyro's z rate integrates to over the same run (angular with
            a gyro), else ``None``.
        seconds: How long the drive took.
    """

    reported: float
    gyro: float | None
    seconds: float


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``calibrate``."""
    p = sub.add_parser(
        "calibrate",
        help="measure odometry calibration factors and write them to the profile",
        description=(
            "Drive by odometry, compare with what was really measured (or, for angular "
            "with a gyro, with the gyro) and write [calibration] linear_scale or "
            "angular_scale to the profile."
        ),
    )
    port_args(p)
    p.add_argument(
        "what",
        metavar="linear|angular",
        choices=("linear", "angular"),
        help="which factor to measure",
    )
    device_arg(p, names)
    p.add_argument(
        "--distance",
        type=positive("distance"),
        default=2.0,
        help="linear: metres to drive by odometry (default %(default)s)",
    )
    p.add_argument(
        "--turns",
        type=positive("turns"),
        default=5.0,
        help="angular: turns in place by odometry (default %(default)s)",
    )
    p.add_argument(
        "--speed",
        type=positive("speed"),
        help=f"m/s (linear, default {LINEAR_SPEED}) or rad/s (angular, default {ANGULAR_SPEED})",
    )
    p.add_argument(
        "--measured",
        type=finite("measured"),
        help="what was really measured (m for linear, turns for angular): no prompt",
    )
    gyro = p.add_mutually_exclusive_group()
    gyro.add_argument(
        "--imu",
        action="store_true",
        default=None,
        help="angular: fit from the gyro, no measurement (the default for a board)",
    )
    gyro.add_argument(
        "--no-imu", dest="imu", action="store_false", help="angular: ask even with a gyro"
    )
    p.add_argument("--write", metavar="FILE", help="the profile to write (default: the one in use)")
    p.add_argument("--dry-run", action="store_true", help="compute the factor, write nothing")
    limit_args(p, "--speed")
    p.add_argument(
        "--timeout", type=positive("timeout"), default=3.0, help="seconds to hear the device"
    )
    record_arg(p)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    if args.measured is not None and args.measured <= 0:
        raise ValueError(f"--measured must be > 0, got {args.measured:g}")
    device = profile(args.device)
    gyro = args.imu if args.imu is not None else _has_gyro(device.device)
    if args.measured is not None and not (args.what == "angular" and gyro):
        _believable(args)
    check_record(args, "calibrate")
    return calibrate(device, port, args)


def _believable(args: argparse.Namespace) -> None:
    """Refuse, before anything moves, a ``--measured`` that the end of the run would
    refuse: the odometry reports what it is asked to drive, so the new factor is known
    (`combined_scale`'s rule) before the drive.

    Raises:
        ChassisError: The factor would fall outside `SCALE_RANGE` (one line).
    """
    linear = args.what == "linear"
    name = "linear_scale" if linear else "angular_scale"
    old: float = getattr(_current(*_target(args)), name)
    target, flag, unit = (
        (args.distance, "--distance", "m") if linear else (args.turns, "--turns", "turns")
    )
    try:
        combined_scale(old, target, args.measured, name)
    except ValueError:
        low, high = SCALE_RANGE
        raise ChassisError(
            f"--measured {args.measured:g} {unit} against {flag} {target:g}: {name} would be "
            f"{old * args.measured / target:.3f}, outside {low:g}..{high:g}, so the measurement "
            "is not believable; nothing driven"
        ) from None


def _target(args: argparse.Namespace) -> tuple[Path | None, Path]:
    """The profile in use (read for the factor in use) and the file to write."""
    in_use = find_profile(getattr(args, "config", None))
    written = Path(args.write) if args.write else in_use or Path("chassis-sdk.toml")
    return in_use, written


def _current(in_use: Path | None, written: Path) -> Calibration:
    """The factors in use: the profile's (the file written, if it exists and is another)."""
    source = written if written.is_file() else in_use
    if source is None:
        return Calibration()
    return load_profile(source).calibration or Calibration()


def _has_gyro(dev: Device[Any, Any] | type[Device[Any, Any]]) -> bool:
    return callable(getattr(dev, "imu", None))


async def calibrate(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Run one calibration on ``port`` (see the module) and write the new factor.

    Raises:
        ChassisError: The robot did not move, its odometry went silent, it has no gyro
            for ``--imu``, or the measurement is not believable; nothing is written.
    """
    in_use, written = _target(args)
    current = _current(in_use, written)
    linear = args.what == "linear"
    speed = args.speed or (LINEAR_SPEED if linear else ANGULAR_SPEED)
    limit = args.max_linear if linear else args.max_angular
    if speed > limit:
        unit = "m/s" if linear else "rad/s"
        flag = "--max-linear" if linear else "--max-angular"
        out(f"speed {speed:g} {unit} clamped to {limit:g} {unit} ({flag})")
        speed = limit
    # The profile's limits (accelerations too) and deadman, under the flags; the
    # calibration is the one being measured against.
    options = {**device_options(args, record=args.record), "calibration": current}
    async with device.device(port, **options) as dev:
        await first_frame(dev, args.timeout, device.recognised_by)
        use_gyro = False
        if not linear:
            use_gyro = _has_gyro(dev) if args.imu is None else args.imu
            if use_gyro and not _has_gyro(dev):
                raise ChassisError(f"--imu: a {device.name} has no gyro; measure the turns")
        if linear:
            out(f"driving {args.distance:g} m straight ahead at {speed:g} m/s by odometry")
        else:
            out(f"turning {args.turns:g} turns in place at {speed:g} rad/s by odometry")
        show = progress_line("calibrate")
        try:
            if linear:
                run = await drive_straight(dev, args.distance, speed, show)
            else:
                run = await turn_in_place(dev, args.turns, speed, show, gyro=use_gyro)
        except BaseException:
            show.done("stopped")  # the live line ends before the error is told
            raise
        await dev.stop()
    if linear:
        show.done(f"odometry measured {run.reported:.4f} m in {run.seconds:.1f} s")
        measured = _measured(args, "distance really driven (m)")
        name, old, reported = "linear_scale", current.linear_scale, run.reported
    else:
        turns = run.reported / math.tau
        show.done(f"odometry measured {turns:.4f} turns in {run.seconds:.1f} s")
        if use_gyro:
            measured = (run.gyro or 0.0) / math.tau
            out(f"the gyro measured {measured:.3f} turns")
            if measured < 0.1 * turns:
                raise ChassisError(
                    f"the gyro saw {measured:.3f} turns of {turns:.3f}: is it working?"
                )
        else:
            measured = _measured(args, "turns really made (e.g. 4.9)")
        name, old, reported = "angular_scale", current.angular_scale, turns
    factor = round(combined_scale(old, reported, measured, name), 5)
    out(f"{name} {old:.5f} -> {factor:.5f}")
    if args.dry_run:
        out(f"not written (--dry-run); would set [calibration] {name} = {factor} in {written}")
        return
    update_profile(written, "calibration", {name: factor})
    out(f"written: [calibration] {name} = {factor} in {written}")


def _measured(args: argparse.Namespace, what: str) -> float:
    """``--measured``, else the operator's answer on stdin.

    Raises:
        ChassisError: No answer, or not a number > 0.
    """
    value: float | None = args.measured
    if value is None:
        print(f"{what}: ", end="", flush=True)
        line = sys.stdin.readline()
        if not line.strip():
            raise ChassisError("no measurement entered; nothing written")
        try:
            value = float(line.strip().replace(",", "."))
        except ValueError:
            raise ChassisError(f"{line.strip()!r} is not a number; nothing written") from None
    if not math.isfinite(value) or value <= 0:
        raise ChassisError(f"measured {value:g} is not a positive number; nothing written")
    return value


Show = Callable[[str], None]


async def drive_straight(
    dev: Device[Any, Any], distance: float, speed: float, show: Show
) -> CalibrationRun:
    """Drive straight ahead at ``speed`` (m/s) until the odometry reports ``distance``
    metres, stop, and wait until the robot stands still.

    Raises:
        ChassisError: The robot did not move, or the odometry went silent.
    """

    def progress(total: float, heading: float) -> float:
        show(f"{total:.3f} / {distance:g} m")
        return total

    reported, _, seconds = await _run(dev, (speed, 0.0), distance, progress, "m", gyro=False)
    return CalibrationRun(reported, None, seconds)


async def turn_in_place(
    dev: Device[Any, Any], turns: float, speed: float, show: Show, *, gyro: bool = False
) -> CalibrationRun:
    """Turn in place counter-clockwise at ``speed`` (rad/s) until the odometry reports
    ``turns`` turns, stop, and wait until the robot stands still; with ``gyro``, the
    gyro's z rate (the device's ``imu()``) is integrated over the same run.

    Raises:
        ChassisError: The robot did not move, or the odometry went silent.
    """

    def progress(total: float, heading: float) -> float:
        show(f"{heading / math.tau:.3f} / {turns:g} turns")
        return heading

    target = turns * math.tau
    heading, rotation, seconds = await _run(dev, (0.0, speed), target, progress, "rad", gyro=gyro)
    return CalibrationRun(heading, rotation, seconds)


async def _run(
    dev: Device[Any, Any],
    command: tuple[float, float],
    target: float,
    measure: Callable[[float, float], float],
    unit: str,
    *,
    gyro: bool,
) -> tuple[float, float | None, float]:
    """Drive ``command`` until ``measure(path, heading)`` of the odometry reaches
    ``target``, then stop and wait for standstill: ``(measure, gyro radians or None,
    seconds)``. ``path`` is the distance along the path (m), ``heading`` the unwrapped
    rotation (rad), both since the start."""
    rotation: list[float] = [0.0]
    started = time.monotonic()
    # Longest it may take: the target at the asked speed, three times over, plus ramps.
    speed = max(abs(command[0]), abs(command[1]))
    deadline = started + 3 * target / speed + 10
    dev.reset_odometry()
    samples = dev.odometry()  # after the reset: every sample starts from it
    path = heading = 0.0
    previous: tuple[float, float, float] | None = None
    stopped_at: float | None = None
    still_since: float | None = None
    sent = -math.inf
    with_imu: Any = dev  # a device with a gyro (a Board): checked by _has_gyro
    rates = with_imu.imu() if gyro else None  # subscribed before the robot moves
    async with anyio.create_task_group() as tg:
        if rates is not None:
            tg.start_soon(_integrate_gyro, rates, rotation)
        async with samples:
            while True:
                with anyio.move_on_after(SILENCE) as scope:
                    pose = await anext(samples)
                if scope.cancelled_caught:
                    raise ChassisError(
                        f"no odometry from {dev.port} for {SILENCE:g} s (no telemetry?)"
                    )
                now = time.monotonic()
                if previous is not None:
                    x, y, h = previous
                    path += math.hypot(pose.x - x, pose.y - y)
                    heading += wrap_angle(pose.heading - h)
                previous = (pose.x, pose.y, pose.heading)
                value = measure(path, heading)
                if stopped_at is None:
                    if value >= target:
                        await dev.stop()
                        stopped_at = now
                    elif now - sent >= 0.1:  # within the deadman, as a control loop
                        await dev.set_velocity(*command)
                        sent = now
                    # A tenth of the way the speed asked would have gone: it did not move.
                    if now - started > MOVE_WITHIN and abs(value) < 0.1 * speed * MOVE_WITHIN:
                        raise ChassisError(
                            f"the robot did not move: odometry reports {value:.3f} {unit} "
                            f"after {now - started:.1f} s (e-stop, bumper or driver fault? "
                            "see `chassis-sdk info`)"
                        )
                    if now > deadline:
                        raise ChassisError(
                            f"odometry reached {value:.3f} of {target:.3f} {unit} in "
                            f"{now - started:.0f} s: is the robot blocked?"
                        )
                else:
                    still = abs(pose.linear) < STILL_LINEAR and abs(pose.angular) < STILL_ANGULAR
                    if not still:
                        still_since = None
                    elif still_since is None:
                        still_since = now
                    elif now - still_since >= STILL_FOR or now - stopped_at > 5.0:
                        break
        tg.cancel_scope.cancel()
    return measure(path, heading), rotation[0] if gyro else None, time.monotonic() - started


async def _integrate_gyro(rates: Any, rotation: list[float]) -> None:
    """Integrate the gyro's z rate (rad/s) of ``rates`` into ``rotation[0]`` (rad) until
    cancelled; a gap longer than half a second is not integrated."""
    last: float | None = None
    async with rates:
        async for sample in rates:
            t = sample.timestamp
            if last is not None and 0 < t - last <= 0.5:
                rotation[0] += sample.angular_velocity.z * (t - last)
            last = t
