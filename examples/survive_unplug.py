"""Keep a telemetry loop running across a pulled cable, with ``reconnect=True``.

    python examples/survive_unplug.py [PORT]

With a PORT, pull the USB cable and put it back while it runs (Ctrl-C to stop). Without
one, the example starts the simulator and pulls its cable itself, twice.

What to expect: the loop prints the link state as it changes; during the outage,
commands raise NotConnectedError at once (the robot is never driven by a stale
command), and the same ``async for`` goes on once the port is back.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys

import chassis_sdk
from chassis_sdk import Chassis
from chassis_sdk.sim import ChassisSimulator


async def watch_states(robot: Chassis) -> None:
    async for state in robot.connection_states():
        print(f"link: {state.value}")


async def pull_the_cable(sim: ChassisSimulator) -> None:
    for _ in range(2):
        await asyncio.sleep(1.0)
        print("(simulator: cable pulled)")
        sim.unplug()
        await asyncio.sleep(1.0)
        print("(simulator: cable back)")
        await sim.replug()


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        sim = None
        if port is None:
            sim = await stack.enter_async_context(ChassisSimulator())
            port = sim.port
        robot = await stack.enter_async_context(Chassis(port, reconnect=True))
        await robot.verify()  # the device on the port is a chassis
        async with asyncio.TaskGroup() as tg:
            states = tg.create_task(watch_states(robot))
            cable = tg.create_task(pull_the_cable(sim)) if sim else None
            last_report = 0.0
            async for t in robot.telemetry():
                # Frames buffered before a drop may still be yielded after it: only
                # command an open link (set_velocity would raise NotConnectedError).
                if robot.is_connected:
                    await robot.set_velocity(0.0, 0.2)  # a slow turn
                if t.timestamp - last_report >= 0.5:
                    last_report = t.timestamp
                    print(f"seq {t.seq:5d}  w={t.angular:+.2f} rad/s  "
                          f"reconnects={robot.stats.reconnects}")  # fmt: skip
                if cable is not None and cable.done():
                    break
            await robot.stop()
            states.cancel()
        print("link:", robot.stats)


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
