"""Child process of ``mqtt_fleet.py``: N chassis simulators (50 Hz telemetry each), in
a process of their own, that time the velocity commands they receive.

    python benchmarks/_fleet_simulators.py N

Prints the N pty paths as one JSON list, then reads requests on stdin, one a line:
``K MM SENT`` (robot K, a ``DriveVelocity`` of MM mm/s, published at ``SENT``,
CLOCK_MONOTONIC) and answers each with one line: the milliseconds from ``SENT`` to
simulator K reading that frame off its pty. Ends when stdin closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
import time

from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator


async def wait_for(sim: ChassisSimulator, mm: int, sent: float) -> float:
    """Milliseconds from ``sent`` to ``sim`` reading a velocity of ``mm`` (polled)."""
    frames = sim.firmware.received
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        first = None  # the earliest match: a held velocity is sent again every 20 ms
        for t, c in reversed(frames):
            if t < sent:
                break
            if isinstance(c, DriveVelocity) and c.linear_mm == mm:
                first = t
        if first is not None:
            return (first - sent) * 1000
        await asyncio.sleep(0.0005)
    return float("inf")  # never arrived: the parent counts it as a failure


async def main(n: int) -> None:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    async with contextlib.AsyncExitStack() as stack:
        sims = [await stack.enter_async_context(ChassisSimulator()) for _ in range(n)]
        print(json.dumps([sim.port for sim in sims]), flush=True)
        while line := await reader.readline():
            k, mm, sent = line.split()
            ms = await wait_for(sims[int(k)], int(mm), float(sent))
            print(f"{ms:.6f}", flush=True)


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
