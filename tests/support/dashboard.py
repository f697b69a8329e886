"""What the dashboard's tests share: a simulator, its device and a dashboard serving
it, and whether the simulated wheels turn."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

from chassis_sdk import Board, Chassis
from chassis_sdk.integrations.web import WebDashboard
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .helpers import until

__all__ = ["moving", "served", "until"]


def moving(sim: ChassisSimulator) -> bool:
    """Whether the simulated chassis's wheel targets are not all zero."""
    return any(sim.firmware.target)


@contextlib.asynccontextmanager
async def served(
    *, board: bool = False, web: dict[str, Any] | None = None, **device_options: Any
) -> AsyncIterator[tuple[Any, Any, WebDashboard]]:
    """``(sim, device, dashboard)``: a chassis (or ``board``) simulator over a real
    pty, the device on it with ``device_options``, and a dashboard on a free port with
    ``web`` options."""
    simulator = BoardSimulator() if board else ChassisSimulator()
    device = Board if board else Chassis
    async with (
        simulator as sim,
        device(sim.port, **device_options) as robot,
        WebDashboard(robot, **{"port": 0, **(web or {})}) as dashboard,
    ):
        yield sim, robot, dashboard
