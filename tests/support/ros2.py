"""What the ROS 2 bridge's tests and benchmark share: the velocity frames a simulated
chassis read, a wait on the SDK's own state, and a bridge running for a block."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Any

import anyio

from chassis_sdk.devices.chassis.messages import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

if TYPE_CHECKING:
    from chassis_sdk.integrations.ros2 import Ros2Bridge

__all__ = ["bridged", "drives", "until"]


def drives(sim: ChassisSimulator, since: float = -math.inf) -> list[tuple[float, DriveVelocity]]:
    """The velocity frames the simulator read from ``since`` (monotonic), with their time."""
    return [(t, c) for t, c in sim.firmware.received if isinstance(c, DriveVelocity) and t >= since]


async def until(condition: Callable[[], bool], timeout: float = 5.0) -> None:
    """Until ``condition()`` holds, polled every 2 ms (the simulator's log of frames and
    the bridge's counters have nothing to wait on)."""
    async with asyncio.timeout(timeout):
        while not condition():
            await asyncio.sleep(0.002)


@contextlib.asynccontextmanager
async def bridged(device: Any, **options: Any) -> AsyncIterator[Ros2Bridge]:
    """A :class:`Ros2Bridge` of ``device`` (with ``options``) running for the block, on
    the graph when the block starts; cancelled (the robot stopped) when it ends. (Imported
    here: the benchmark's floor process must not load cyclonedds.)"""
    from chassis_sdk.integrations.ros2 import Ros2Bridge

    bridge = Ros2Bridge(device, **options)
    async with anyio.create_task_group() as tg:
        tg.start_soon(bridge.run)
        await bridge.started.wait()
        yield bridge
        tg.cancel_scope.cancel()
