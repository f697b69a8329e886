"""``chassis_sdk.run`` and the event loop it runs on: uvloop when installed."""

from __future__ import annotations

import asyncio
import sys

import pytest

import chassis_sdk
from chassis_sdk import Chassis
from chassis_sdk.sim import ChassisSimulator


async def _loop_module() -> str:
    return type(asyncio.get_running_loop()).__module__


def test_run_uses_uvloop_when_it_is_installed(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("uvloop")
    monkeypatch.delenv("CHASSIS_SDK_LOOP", raising=False)
    assert chassis_sdk.run(_loop_module()).startswith("uvloop")
    assert chassis_sdk.run(_loop_module(), uvloop=True).startswith("uvloop")
    assert chassis_sdk.run(_loop_module(), uvloop=False).startswith("asyncio")
    monkeypatch.setenv("CHASSIS_SDK_LOOP", "asyncio")
    assert chassis_sdk.run(_loop_module()).startswith("asyncio")


def test_run_without_uvloop(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "uvloop", None)  # as if not installed
    assert chassis_sdk.run(_loop_module()).startswith("asyncio")
    with pytest.raises(ImportError, match=r"chassis-sdk\[uvloop\]"):
        chassis_sdk.run(_loop_module(), uvloop=True)


def test_a_chassis_drives_and_stops_on_uvloop() -> None:
    pytest.importorskip("uvloop")

    async def drive() -> tuple[str, list[object]]:
        async with ChassisSimulator() as sim:
            async with Chassis(sim.port) as robot:
                await robot.set_velocity(0.2, 0.0)
                n = 0
                async for _ in robot.telemetry():
                    n += 1
                    if n == 10:
                        break
                assert await robot.get_firmware_version() > 0
            return await _loop_module(), [c for _, c in sim.firmware.received]

    module, received = chassis_sdk.run(drive(), uvloop=True)
    assert module.startswith("uvloop")
    from chassis_sdk.protocol import DriveVelocity

    drives = [c for c in received if isinstance(c, DriveVelocity)]
    assert drives[0].linear_mm == 200
    assert drives[-1] == DriveVelocity(0, 0.0)


async def test_the_tests_run_on_the_loop_asked_for() -> None:
    import os

    wanted = os.environ.get("CHASSIS_SDK_TEST_LOOP", "asyncio")
    assert (await _loop_module()).startswith(wanted)
