"""Reflexes and goals as fast as they must be, over a real pty, against a firmware
process (issue 42's targets).

    python benchmarks/reflexes.py            # every transport, side by side
    python benchmarks/reflexes.py --quick    # fewer samples, the default transport (CI)

Three figures:

* **reflex reaction**: from the firmware process's ``os.write`` of a telemetry frame
  with the front bumper bit set to the arrival, at the firmware, of the first zero
  velocity frame, while the application drives (a bumper every 4th frame at 50 Hz;
  after each, the application drives again when the bumper clears). p50 / p99 over
  ``N_HAZARDS`` hits. Target: p99 <= one telemetry period + 5 ms (25 ms).
  **Floor**, in the same run, against the same firmware: ``add_reader``, one
  ``os.read`` per wake-up, the status byte checked in place and a zero frame written
  in the same callback: the least any process can do.
* **cancel -> zero**: ``drive_distance`` cancelled at a random moment of its drive ->
  the first zero frame's arrival; ``N_CANCELS`` times. Target p99 <= 25 ms. Floor: the
  application's own ``await robot.stop()`` while a velocity is held, measured the same
  way.
* **false reflexes over an hour of normal driving**: the reflex rules fed an hour of
  the simulated chassis and board (the firmware models stepped on a virtual clock at
  their telemetry rates: accelerating, cruising, turning, braking, reversing, within
  their limits, ramps as written), counted. Target 0.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import random
import statistics
import subprocess
import sys
import time
import tty
from pathlib import Path
from typing import Any

FIRMWARE = Path(__file__).with_name("_hazard_firmware.py")
BACKENDS = ["pyserial-asyncio", "pyserial-asyncio-fast", "serialx"]
PERIOD = 0.02  # 50 Hz telemetry
EVERY = 4  # a bumper hit every 4th frame
N_HAZARDS = 1000
N_CANCELS = 300
HOUR = 3600.0
QUICK: list[str] = []


def summary(samples: list[float]) -> dict[str, float]:
    """p50, p99 and max, in milliseconds."""
    if len(samples) < 2:
        return {"p50": math.nan, "p99": math.nan, "max": math.nan, "n": len(samples)}
    q = statistics.quantiles(samples, n=100, method="inclusive")
    return {"p50": q[49] * 1e3, "p99": q[98] * 1e3, "max": max(samples) * 1e3, "n": len(samples)}


class Firmware:
    """The firmware process on the master side of a new pty."""

    def __init__(self) -> None:
        self.proc: asyncio.subprocess.Process | None = None
        self.slave = -1

    async def __aenter__(self) -> Firmware:
        master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable, str(FIRMWARE), str(master), pass_fds=(master,),
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, limit=1 << 26,
        )  # fmt: skip
        os.close(master)
        return self

    async def run(self, frames: int, every: int) -> dict[str, Any]:
        assert self.proc is not None and self.proc.stdin is not None  # noqa: PT018
        assert self.proc.stdout is not None
        self.proc.stdin.write(f"run {frames} {PERIOD} {every}\n".encode())
        await self.proc.stdin.drain()
        result: dict[str, Any] = json.loads(await self.proc.stdout.readline())
        return result

    async def __aexit__(self, *exc: object) -> None:
        assert self.proc is not None and self.proc.stdin is not None  # noqa: PT018
        self.proc.stdin.write(b"quit\n")
        await self.proc.wait()
        os.close(self.slave)


def reactions(hazards: list[float], drives: list[list[float]]) -> tuple[list[float], int]:
    """Each hit's time to the first zero frame after it, if the robot was driving when
    it came (the last frame before it not a zero); and the hits never answered."""
    out, missed = [], 0
    for h in hazards:
        before = [mm for t, mm in drives if t < h]
        if not before or before[-1] == 0:
            continue  # not driving then (it had not driven again yet)
        zero = next((t for t, mm in drives if t >= h and mm == 0), None)
        if zero is None:
            missed += 1
        else:
            out.append(zero - h)
    return out, missed


async def floor_reaction(frames: int) -> dict[str, Any]:
    """The least a process can do: the status byte checked in the read callback, a zero
    written there; a velocity written again when a frame without the bit comes."""
    from chassis_sdk.protocol import ChassisEncoder, DriveVelocity

    encoder = ChassisEncoder()
    zero, drive = encoder.encode(DriveVelocity(0, 0.0)), encoder.encode(DriveVelocity(300, 0.0))
    loop = asyncio.get_running_loop()
    async with Firmware() as fw:
        fd = fw.slave
        os.set_blocking(fd, False)
        pending = bytearray()
        hit = [False]

        def readable() -> None:
            pending.extend(os.read(fd, 4096))
            while len(pending) >= 28:
                bumper = bool(pending[9] & 0x04)
                del pending[:28]
                if bumper and not hit[0]:
                    os.write(fd, zero)
                elif not bumper and hit[0]:
                    os.write(fd, drive)
                hit[0] = bumper

        os.write(fd, drive)
        loop.add_reader(fd, readable)
        try:
            result = await fw.run(frames, EVERY)
        finally:
            loop.remove_reader(fd)
    times, missed = reactions(result["hazards"], result["drives"])
    return {"reaction": summary(times), "missed": missed}


async def sdk_reaction(frames: int) -> dict[str, Any]:
    """The SDK: the default policy's bumper reflex, the application driving again on
    each ``BUMPER_CLEARED``."""
    from chassis_sdk import Chassis, EventKind

    async with Firmware() as fw, Chassis(os.ttyname(fw.slave), resend_interval=0.05) as robot:
        await robot.set_velocity(0.3, 0.0, duration=5.0)

        async def again() -> None:
            async for event in robot.events():
                if event.kind is EventKind.BUMPER_CLEARED:
                    await robot.set_velocity(0.3, 0.0, duration=5.0)

        task = asyncio.create_task(again())
        result = await fw.run(frames, EVERY)
        task.cancel()
        backend = robot.transport_backend
        acted = robot.reflexes_acted
    times, missed = reactions(result["hazards"], result["drives"])
    return {"backend": backend, "reaction": summary(times), "missed": missed, "acted": acted}


def _zeros_after(marks: list[float], drives: list[list[float]]) -> list[float]:
    out = []
    for m in marks:
        zero = next((t for t, mm in drives if t >= m and mm == 0), None)
        if zero is not None:
            out.append(zero - m)
    return out


async def cancels(n: int) -> dict[str, Any]:
    """``drive_distance`` cancelled mid-drive, and the floor: ``stop()`` of a held
    velocity; each to the first zero frame's arrival."""
    from chassis_sdk import Chassis

    rng = random.Random(42)
    frames = int((n * 0.2 + 1.0) / PERIOD)  # telemetry for as long as the cancels take
    async with Firmware() as fw, Chassis(os.ttyname(fw.slave)) as robot:
        running = asyncio.create_task(fw.run(frames, 0))
        await robot.odometry().__anext__()
        cancelled, stopped = [], []
        for _ in range(n):
            goal = asyncio.create_task(robot.drive_distance(100.0))
            await asyncio.sleep(rng.uniform(0.05, 0.1))
            cancelled.append(time.monotonic())
            goal.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await goal
            await robot.set_velocity(0.2, 0.0, duration=1.0)
            await asyncio.sleep(rng.uniform(0.02, 0.05))
            stopped.append(time.monotonic())
            await robot.stop()
        result = await running
    return {
        "cancel": summary(_zeros_after(cancelled, result["drives"])),
        "stop": summary(_zeros_after(stopped, result["drives"])),
    }


def false_reflexes(seconds: float) -> dict[str, Any]:
    """An hour of normal driving (the firmware models on a virtual clock) through the
    reflex rules: the triggers counted."""
    from chassis_sdk.core.motion.safety import Reflexes, SafetyPolicy
    from chassis_sdk.core.motion.watchdog import MotionLimits
    from chassis_sdk.devices.board.firmware import BoardFirmware
    from chassis_sdk.devices.board.protocol import velocity_command
    from chassis_sdk.devices.chassis.firmware import ChassisFirmware
    from chassis_sdk.protocol import BoardEncoder, ChassisEncoder, DriveVelocity

    rng = random.Random(7)
    board_encoder = BoardEncoder()
    chassis, board = ChassisFirmware(), BoardFirmware()
    rules = {"chassis": Reflexes(SafetyPolicy()), "board": Reflexes(SafetyPolicy())}
    limits = MotionLimits(max_linear=1.0, max_angular=1.5, linear_acceleration=1.0)
    encoder = ChassisEncoder()
    triggers: list[str] = []
    t, written, target, change = 0.0, 0.0, (0.0, 0.0), 0.0
    chassis.on_connect(0.0)
    board.on_connect(0.0)
    while t < seconds:
        if t >= change:  # a new leg: cruise, turn, brake to a stop, or reverse
            kind = rng.choice(["cruise", "turn", "stop", "reverse", "arc"])
            v = {"cruise": rng.uniform(0.2, 1.0), "turn": 0.0, "stop": 0.0,
                 "reverse": -rng.uniform(0.1, 0.5), "arc": rng.uniform(0.2, 0.8)}[kind]  # fmt: skip
            w = rng.uniform(-1.5, 1.5) if kind in ("turn", "arc") else 0.0
            target, change = (v, w), t + rng.uniform(1.0, 8.0)
        # the watchdog's ramp at 20 ms: what is written
        step = (limits.linear_acceleration or 1.0) * PERIOD
        written = written + max(-step, min(step, target[0] - written))
        command = (written, target[1])
        chassis.receive(encoder.encode(DriveVelocity(round(command[0] * 1000), command[1])), t)
        board.receive(board_encoder.encode(velocity_command(*command)), t)
        t += PERIOD
        chassis.poll(t)
        tel = chassis.telemetry()
        for trig in rules["chassis"].speeds(command[0], tel.linear, t):
            triggers.append(f"chassis {trig.hazard} at {t:.2f}")
        board.poll(t)
        imu = board.imu_sample()
        for trig in rules["board"].imu(imu.accel.x, imu.accel.y, imu.accel.z, t):
            triggers.append(f"board {trig.hazard} at {t:.2f}")
    return {"seconds": seconds, "false": len(triggers), "first": triggers[:5]}


def run_one(what: str, backend: str) -> dict[str, Any]:
    env = dict(os.environ, CHASSIS_SDK_BACKEND=backend if backend != "floor" else "")
    out = subprocess.run(
        [sys.executable, __file__, "--one", what, "--backend", backend, *QUICK],
        env=env, check=True, capture_output=True, text=True,
    )  # fmt: skip
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def main() -> None:
    global N_HAZARDS, N_CANCELS, HOUR
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--one", choices=["reaction", "cancel"], help=argparse.SUPPRESS)
    parser.add_argument("--backend", choices=["floor", *BACKENDS])
    parser.add_argument("--quick", action="store_true", help="fewer samples (for CI)")
    parser.add_argument("--json-file", metavar="FILE", help="also write every figure to FILE")
    args = parser.parse_args()
    if args.quick:
        QUICK.append("--quick")
        N_HAZARDS, N_CANCELS, HOUR = 100, 20, 600.0
    frames = N_HAZARDS * EVERY + 10
    if args.one:
        if args.backend and args.backend != "floor":
            os.environ["CHASSIS_SDK_BACKEND"] = args.backend
        if args.one == "reaction":
            job = floor_reaction(frames) if args.backend == "floor" else sdk_reaction(frames)
        else:
            job = cancels(N_CANCELS)
        print(json.dumps(asyncio.run(job)))
        return
    if args.backend and args.backend != "floor":
        backends = [args.backend]
    else:
        backends = BACKENDS[:1] if args.quick else BACKENDS
    report: dict[str, Any] = {"floor": run_one("reaction", "floor"), "sdk": {}}
    floor = report["floor"]["reaction"]
    print(f"reflex reaction (bumper frame written -> first zero frame read), ms; "
          f"{N_HAZARDS} hits at 50 Hz; target p99 <= 25 ms")  # fmt: skip
    print(f"{'':<24}{'p50':>18}{'p99':>18}{'max':>18}  missed")
    print(f"{'floor':<24}{floor['p50']:>18.2f}{floor['p99']:>18.2f}{floor['max']:>18.2f}"
          f"  {report['floor']['missed']}")  # fmt: skip
    for backend in backends:
        try:
            r = run_one("reaction", backend)
        except subprocess.CalledProcessError as exc:
            print(f"{backend}: not measured ({exc.stderr.strip().splitlines()[-1]})")
            continue
        c = run_one("cancel", backend)
        report["sdk"][backend] = {"reaction": r, "cancel": c}
        got = r["reaction"]
        cells = "".join(
            f"{f'{got[q]:.2f} ({got[q] / floor[q]:.1f}x)':>18}" for q in ("p50", "p99", "max")
        )
        print(f"{backend:<24}{cells}  {r['missed']}")
    print(
        f"\ncancel -> zero, ms ({N_CANCELS} goals cancelled mid-drive; floor: stop() "
        "of a held velocity, same run); target p99 <= 25 ms"
    )
    print(f"{'':<24}{'cancel p50':>14}{'cancel p99':>14}{'stop p50':>14}{'stop p99':>14}")
    for backend, figures in report["sdk"].items():
        c = figures["cancel"]
        print(f"{backend:<24}{c['cancel']['p50']:>14.2f}{c['cancel']['p99']:>14.2f}"
              f"{c['stop']['p50']:>14.2f}{c['stop']['p99']:>14.2f}")  # fmt: skip
    fr = false_reflexes(HOUR)
    report["false_reflexes"] = fr
    print(
        f"\nfalse reflexes over {fr['seconds'] / 60:.0f} min of normal driving "
        f"(chassis stall, board tilt/impact): {fr['false']} (target 0) {fr['first']}"
    )
    print(f"(machine: {os.cpu_count()} cores; {sys.platform}; Python {sys.version.split()[0]})")
    if args.json_file:
        Path(args.json_file).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
