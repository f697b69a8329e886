"""Small helpers shared by the tests: the transports the failure tests run on, a
heartbeat of the event loop, a wait on the SDK's own state (from a coroutine or a plain
test) and on a device's next connection state, the velocity commands a simulated
chassis read, the descriptors held on a port, a firmware stand-in on its own thread for
tests that block or replace the loop, a program killed while it records, and the tasks
an integration runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import signal
import struct
import sys
import threading
import time
import tty
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

import chassis_sdk.integrations
from chassis_sdk.protocol import DriveVelocity

from .standin import ChassisStandIn, Received, frame_a

if TYPE_CHECKING:
    from chassis_sdk import ConnectionState
    from chassis_sdk.sim import ChassisSimulator

__all__ = [
    "TRANSPORTS",
    "Heartbeat",
    "ThreadedPeer",
    "drives",
    "kill_while_recording",
    "next_state",
    "open_fds_on",
    "tasks_of",
    "until",
    "wait_until",
]

TRANSPORTS = [pytest.param(False, id="pty"), pytest.param(True, id="tcp")]
# Where the package that runs is (an installed one, in CI's other CPythons), not the tree.
INTEGRATIONS = Path(chassis_sdk.integrations.__file__).resolve().parent


class Heartbeat:
    """Measures how long the event loop goes without running a 5 ms sleeper."""

    def __init__(self) -> None:
        self.max_gap = 0.0
        self._task: asyncio.Task[None] | None = None

    async def _beat(self) -> None:
        while True:
            t = time.monotonic()
            await asyncio.sleep(0.005)
            self.max_gap = max(self.max_gap, time.monotonic() - t)

    async def __aenter__(self) -> Heartbeat:
        self._task = asyncio.create_task(self._beat())
        await asyncio.sleep(0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task


async def until(condition: Callable[[], bool], timeout: float = 5.0, poll: float = 0.005) -> float:
    """Wait for a condition of the SDK's own state (its counters have no event);
    return how long it took (s)."""
    start = time.monotonic()
    async with asyncio.timeout(timeout):
        while not condition():
            await asyncio.sleep(poll)
    return time.monotonic() - start


def wait_until(condition: Callable[[], bool], timeout: float = 5.0) -> float:
    """Wait (from a plain test, not a coroutine) for state held in another thread;
    return how long it took (s)."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"not within {timeout} s")
        time.sleep(0.005)
    return time.monotonic() - start


async def next_state(
    states: AsyncIterator[ConnectionState], timeout: float = 5.0
) -> ConnectionState:
    """The next state of ``connection_states()`` (TimeoutError after ``timeout``)."""
    async with asyncio.timeout(timeout):
        return await anext(states)


def drives(sim: ChassisSimulator) -> list[DriveVelocity]:
    """The velocity commands the simulated chassis read, in order."""
    return [c for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]


def open_fds_on(path: str) -> int:
    """Descriptors this process holds on ``path``."""
    target = os.path.realpath(path)
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            n += os.readlink(f"/proc/self/fd/{fd}") == target
    return n


def tasks_of(module: str) -> list[str]:
    """The running tasks that run a function of ``chassis_sdk/integrations/<module>``
    (the first such function of each, through anyio's wrapper), by the function's name."""
    path = str(INTEGRATIONS / module)
    found = []
    for task in asyncio.all_tasks():
        coro: Any = task.get_coro()
        while coro is not None and hasattr(coro, "cr_code"):
            if coro.cr_code.co_filename == path:
                found.append(coro.cr_code.co_name)
                break
            coro = coro.cr_await
    return sorted(found)


class ThreadedPeer:
    """A protocol A firmware stand-in on its own thread: it times what arrives on the
    wire while the test's event loop is blocked or replaced, and streams telemetry."""

    def __init__(self) -> None:
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self._slave = slave
        self.port = os.ttyname(slave)
        self.chunks: list[tuple[float, bytes]] = []
        self._arrived = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        seq = 0
        next_telemetry = time.monotonic()
        while not self._stop.is_set():
            ready = select.select([self._master], [], [], 0.005)[0]
            if ready:
                with contextlib.suppress(OSError), self._arrived:
                    self.chunks.append((time.monotonic(), os.read(self._master, 4096)))
                    self._arrived.notify_all()
            if time.monotonic() >= next_telemetry:
                payload = struct.pack("<HHHhhhhhh", 246, 0, 4, 0, 0, 0, 0, 0, 0)
                with contextlib.suppress(OSError):
                    os.write(self._master, frame_a(0x81, payload, seq))
                seq = (seq + 1) & 0xFFFF
                next_telemetry += 0.02

    def drive_frames(self) -> list[Received]:
        out: list[Received] = []
        buf = bytearray()
        parser = ChassisStandIn()
        for t, data in list(self.chunks):
            buf += data
            out += [r for r in parser.parse(buf, t) if r.kind == 0x02]
        return out

    def wait_for(self, predicate: Callable[[list[Received]], bool], timeout: float = 3.0) -> None:
        """Block until ``predicate(drive frames)`` holds (woken by each chunk read)."""
        with self._arrived:
            assert self._arrived.wait_for(lambda: predicate(self.drive_frames()), timeout)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        os.close(self._master)
        os.close(self._slave)


# A program that records while driving, killed with SIGKILL by kill_while_recording.
_RECORDING_KILLED = """
import asyncio, sys
from chassis_sdk import Chassis
from chassis_sdk.recording.ros2 import rosbag
async def main():
    async with Chassis(sys.argv[1], record=RECORD) as robot:
        n = 0
        async for t in robot.telemetry():
            await robot.set_velocity(0.1, 0.0)
            n += 1
            if n == 100:
                print("recorded", flush=True)
asyncio.run(main())
"""


async def kill_while_recording(
    port: str, path: str, record: str, cwd: str | os.PathLike[str]
) -> None:
    """Run a program that drives the device on ``port`` while recording with
    ``record=<record>`` (an expression of ``sys.argv[2]``, the file ``path``), and
    ``kill -9`` it after 100 telemetry frames (2 s)."""
    program = _RECORDING_KILLED.replace("RECORD", record)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", program, port, path, stdout=asyncio.subprocess.PIPE, cwd=cwd
    )
    assert proc.stdout is not None
    async with asyncio.timeout(20):
        assert (await proc.stdout.readline()).startswith(b"recorded")
    proc.send_signal(signal.SIGKILL)
    await proc.wait()
