"""Scenarios of a slow or stalled device, shared by the failure tests
(tests/test_stopping.py, tests/test_requests.py, tests/test_connecting.py) and the
figures that go with them (benchmarks/stalled_port.py, which loads this file by path
so that an older ``chassis_sdk`` first on ``PYTHONPATH`` is measured in the same
scenarios).

Nothing here imports ``chassis_sdk`` at import time: each scenario imports what it
drives when it runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from .standin import ChassisStandIn, Received, drive_frames, frame_a

__all__ = ["NumberedReplies", "drive_until_the_link_blocks", "first_telemetry", "own_answers"]


@dataclass
class NumberedReplies(ChassisStandIn):
    """Answers the n-th 0x07 request with version n, after ``delays[n - 1]`` s (or
    ``latency`` s past the list)."""

    delays: list[float] = field(default_factory=list)
    latency: float = 0.0

    def on_frame(self, rec: Received) -> None:
        if rec.kind != 0x07:
            super().on_frame(rec)
            return
        n = len(self.of_kind(0x07))
        reply = frame_a(0x87, struct.pack("<H", n), self.next_seq(0x87))
        delay = self.delays[n - 1] if n <= len(self.delays) else self.latency
        asyncio.get_running_loop().call_later(delay, self.send, reply)


async def own_answers(dev: NumberedReplies, robot: Any, calls: int) -> list[tuple[list[int], Any]]:
    """``calls`` firmware-version requests in a row, each as (the numbers of its own
    attempts, the number of the request whose reply it returned, or ``None``)."""
    from chassis_sdk import RequestTimeoutError

    answers: list[tuple[list[int], Any]] = []
    for _ in range(calls):
        before = len(dev.of_kind(0x07))
        try:
            answer = await robot.get_firmware_version()
        except RequestTimeoutError:
            answer = None
        async with asyncio.timeout(5):  # every attempt read by the stand-in
            while len(dev.frames) < robot.stats.frames_sent:
                await asyncio.sleep(0.005)
        answers.append((list(range(before + 1, len(dev.of_kind(0x07)) + 1)), answer))
    return answers


async def drive_until_the_link_blocks(dev: ChassisStandIn, robot: Any) -> asyncio.Task[None]:
    """A control task driving at 0.5 m/s as fast as the loop lets it; once the device
    has a drive frame, it stops reading (a pty's kernel buffer filled at once, as
    minutes of that would), until the port takes nothing more (frames are replaced)."""
    from chassis_sdk import NotConnectedError

    async def control() -> None:
        with contextlib.suppress(NotConnectedError):
            while True:
                await robot.set_velocity(0.5, 0.0)
                await asyncio.sleep(0)

    task = asyncio.create_task(control())
    await dev.wait_for(lambda fs: bool(drive_frames(fs)))  # the robot drives at 0.5 m/s
    dev.stop_reading()
    dev.fill_line()
    async with asyncio.timeout(20):
        while robot.stats.frames_discarded < 3:
            await asyncio.sleep(0.005)
    return task


async def first_telemetry(window: float = 0.0) -> tuple[float, int]:
    """A simulator at 1 kHz runs unread until it drops bytes (its line is full, as a
    device left powered with no host); then a ``Chassis`` opens it. Returns the age of
    the first telemetry message (from the simulator's write to the SDK's receipt) and
    how many more arrived within ``window`` seconds of it."""
    from chassis_sdk import Chassis
    from chassis_sdk.protocol import ChassisDecoder, Telemetry
    from chassis_sdk.sim import ChassisSimulator, ChassisSpec

    produced: list[tuple[float, bytes]] = []
    async with ChassisSimulator(ChassisSpec(telemetry_period=0.001)) as sim:
        send = sim.send

        def record(data: bytes) -> None:
            produced.append((time.monotonic(), data))
            send(data)

        sim.send = record  # type: ignore[method-assign]
        async with asyncio.timeout(30):
            while sim.bytes_discarded == 0:
                await asyncio.sleep(0.05)
        got: list[Telemetry] = []
        async with Chassis(sim.port) as robot, asyncio.timeout(5):
            async for t in robot.telemetry():
                got.append(t)
                if t.timestamp - got[0].timestamp >= window:
                    break
    decoder = ChassisDecoder()
    made_at: dict[int, float] = {}
    for at, data in produced:
        for m in decoder.feed(data):
            if isinstance(m, Telemetry):
                made_at.setdefault(m.seq, at)
    return got[0].timestamp - made_at[got[0].seq], len(got) - 1
