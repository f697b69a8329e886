"""The port under a slow or stalled device, on every transport: the figures behind the
safety promises of issue 23's last three points (not speed: what the device gets).

    python benchmarks/stalled_port.py [--quick]
    PYTHONPATH=/path/to/an/older/checkout python benchmarks/stalled_port.py   # "before"

Printed per transport (pyserial-asyncio, pyserial-asyncio-fast, serialx: each run in a
child process with ``CHASSIS_SDK_BACKEND`` set):

* **replies on a slow device**: four ``get_firmware_version()`` calls in a row with
  ``request_timeout`` 0.3 s and ``retries=2`` against a stand-in that answers every
  request after 1.1x, 1.5x and 3x that, numbered by the request it answers; each call
  as ``(its own attempts, the request whose reply it returned)``, and whether every
  reply answered its own call (the goal: always);
* **the last frame a stalled device gets**: a control task drives at 0.5 m/s, the
  device stops reading, ``close()`` is called; the device reads again 0.4 s or 6 s
  after it stopped (pty and TCP). Printed: how long ``close()`` took, the last drive
  frame the device got (the goal: 0 mm/s), and the drive frames it got after reading
  again;
* **the first telemetry after an unread line**: a simulator at 1 kHz runs unread until
  it drops bytes; then a ``Chassis`` opens it. Printed: the age of the first telemetry
  message (from the simulator's write to the SDK's receipt) and how many frames came in
  the first 30 ms (the floor: a fresh line gives 30).

The scenarios and stand-ins are the tests' own (tests/support/stalls.py, loaded from this
checkout by path), so an older ``chassis_sdk`` first on ``PYTHONPATH`` is measured in
the same scenarios against the same devices.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib.util
import inspect
import json
import os
import platform
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from _support import support

ROOT = Path(__file__).resolve().parent.parent
BACKENDS = {
    "pyserial-asyncio": "serial_asyncio",
    "pyserial-asyncio-fast": "serial_asyncio_fast",
    "serialx": "serialx",
}
TIMEOUT = 0.3


def _scenarios() -> Any:
    """tests/support/stalls.py (and the stand-ins it uses) from this checkout."""
    return support("stalls")


async def _replies(factor: float, tcp: bool) -> dict[str, Any]:
    from chassis_sdk import Chassis

    stalls = _scenarios()
    async with (
        stalls.NumberedReplies(noise=False, tcp=tcp, latency=factor * TIMEOUT) as dev,
        Chassis(dev.port, request_timeout=TIMEOUT, retries=2) as robot,
    ):
        calls = await stalls.own_answers(dev, robot, 4)
    right = all(a is None or a in own for own, a in calls)
    return {"factor": factor, "tcp": tcp, "calls": calls, "every reply its own": right}


async def _stall(stall: float, tcp: bool) -> dict[str, Any]:
    from chassis_sdk import Chassis

    stalls = _scenarios()
    standin = sys.modules["_tests.standin"]
    options: dict[str, Any] = {}
    if "close_linger" in inspect.signature(Chassis).parameters:
        options["close_linger"] = stall + 3.0
    async with standin.ChassisStandIn(noise=False, tcp=tcp, tcp_rcvbuf=4096) as dev:
        robot = Chassis(dev.port, **options)
        await robot.connect()
        dev.release_line()
        stalled = time.monotonic()
        task = await stalls.drive_until_the_link_blocks(dev, robot)
        t0 = time.monotonic()
        await robot.close()
        closing = time.monotonic() - t0
        await task
        read_before = len(standin.drive_frames(dev.frames))
        await asyncio.sleep(max(0.0, stall - (time.monotonic() - stalled)))
        dev.resume_reading()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(dev.eof.wait(), 5.0)
        drives = standin.drive_frames(dev.frames)
    last = struct.unpack_from("<Hh", drives[-1].payload)[1] if drives else None
    return {
        "stall": stall,
        "tcp": tcp,
        "close s": round(closing, 3),
        "last frame mm/s": last,
        "frames after reading again": len(drives) - read_before,
    }


async def _first_telemetry() -> dict[str, Any]:
    age, more = await _scenarios().first_telemetry(window=0.03)
    return {"age of the first s": round(age, 4), "frames in the first 30 ms": more}


async def _all(quick: bool) -> dict[str, Any]:
    out: dict[str, Any] = {"replies": [], "stall": [], "first": None}
    for factor in (1.1, 1.5, 3.0):
        out["replies"].append(await _replies(factor, False))
    for tcp in (False, True):
        for stall in (0.4,) if quick else (0.4, 6.0):
            out["stall"].append(await _stall(stall, tcp))
    out["first"] = await _first_telemetry()
    return out


def _child(quick: bool) -> None:
    print(json.dumps(asyncio.run(_all(quick))))


def _start_child(backend: str, quick: bool) -> subprocess.Popen[str]:
    """This script's ``--child`` on one transport (``CHASSIS_SDK_BACKEND``)."""
    env = {**os.environ, "CHASSIS_SDK_BACKEND": backend}
    argv = [sys.executable, __file__, "--child"] + (["--quick"] * quick)
    return subprocess.Popen(
        argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def _finish(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    """A child's exit code, output and errors, once it ends."""
    out, err = proc.communicate(timeout=600)
    return proc.returncode, out, err


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the 0.4 s stall only")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args.quick)
        return
    import chassis_sdk

    print(f"stalled_port.py: chassis_sdk from {Path(chassis_sdk.__file__).parent}")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores,")
    print(f"  Python {platform.python_version()}, load {os.getloadavg()[0]:.2f}")
    # One child per transport. The quick mode (CI: it must run and print) runs them at
    # once, since they mostly wait on stalled devices; the full one, one at a time.
    installed = [b for b, module in BACKENDS.items() if importlib.util.find_spec(module)]
    done: dict[str, tuple[int, str, str]] = {}
    if args.quick:
        started = {backend: _start_child(backend, True) for backend in installed}
        done = {backend: _finish(proc) for backend, proc in started.items()}
    for backend in BACKENDS:
        if backend not in installed:
            print(f"\n== {backend}: not installed, skipped")
            continue
        code, out, err = done[backend] if args.quick else _finish(_start_child(backend, False))
        if code != 0:
            print(f"\n== {backend}: failed\n{err[-2000:]}")
            sys.exit(1)
        figures = json.loads(out.strip().splitlines()[-1])
        print(f"\n== {backend}")
        print(f"replies on a slow device (request_timeout {TIMEOUT} s, retries 2, pty):")
        for r in figures["replies"]:
            calls = ", ".join(f"({own}, {answer})" for own, answer in r["calls"])
            verdict = "every reply its own call" if r["every reply its own"] else "WRONG"
            print(f"  latency {r['factor']}x: {calls}  -> {verdict}")
        print("the last frame a stalled device gets (goal: 0 mm/s):")
        for s in figures["stall"]:
            print(
                f"  {'tcp' if s['tcp'] else 'pty'}, reads again after {s['stall']} s: "
                f"close() {s['close s']} s, last frame {s['last frame mm/s']} mm/s, "
                f"{s['frames after reading again']} drive frame(s) after reading again"
            )
        f = figures["first"]
        print(
            f"first telemetry after an unread line: {f['age of the first s'] * 1000:.1f} ms "
            f"old; {f['frames in the first 30 ms']} frames in its first 30 ms "
            "(floor, a fresh 1 kHz line: 30)"
        )
    print(f"\nload after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
