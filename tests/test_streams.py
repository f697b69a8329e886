"""Telemetry streams: leaving an ``async for`` loop unsubscribes at once, and sequence
gaps are counted right whichever way the device numbers its frames (field hardening,
issue 11).
"""

from __future__ import annotations

from typing import Any

import pytest

from chassis_sdk import Chassis
from chassis_sdk.sim import ChassisSimulator, ChassisSpec

from .support.helpers import until
from .support.standin import ChassisStandIn

pytestmark = pytest.mark.integration

# --- leaving a loop unsubscribes at once ---------------------------------------------------------


async def test_leaving_a_loop_unsubscribes_even_while_the_subscription_is_held() -> None:
    async with (
        ChassisStandIn(noise=False, telemetry_period=0.005) as dev,
        Chassis(dev.port, queue_size=4) as robot,
    ):
        subs = []

        async def returns_from_the_loop() -> None:
            sub = robot.telemetry()
            subs.append(sub)
            async for _ in sub:
                return

        async def raises_in_the_loop() -> None:
            sub = robot.telemetry()
            subs.append(sub)
            async for _ in sub:
                raise KeyError("boom")

        held = robot.telemetry()
        async for _ in held:
            break
        assert len(robot._telemetry) == 0
        await returns_from_the_loop()
        assert len(robot._telemetry) == 0
        with pytest.raises(KeyError):
            await raises_in_the_loop()
        assert len(robot._telemetry) == 0
        # The held subscriptions buffer nothing and drop nothing from now on.
        await until(lambda: dev.seq > 40)
        assert robot.stats.queue_drops == 0
        async for _ in held:  # a loop left is a subscription ended
            raise AssertionError("a closed subscription yielded")


# --- sequence gaps under either numbering --------------------------------------------------------


@pytest.mark.parametrize("per_id", [False, True], ids=["shared-counter", "per-id-counters"])
async def test_sequence_gaps_are_right_under_either_numbering(per_id: bool) -> None:
    async with (
        ChassisStandIn(noise=False, per_id_seq=per_id) as dev,
        Chassis(dev.port) as robot,
    ):
        for _ in range(30):  # replies interleave with telemetry
            await robot.get_firmware_version()
            await robot.get_hardware_version()
        assert robot.stats.sequence_gaps == 0, "false gaps"
        assert robot.sequence_scheme == ("per-id" if per_id else "shared")
        async with robot.telemetry() as frames:  # the device's telemetry is seen
            for _ in range(3):
                await anext(frames)
        dev.seq += 5  # a real break
        await until(lambda: robot.stats.sequence_gaps == 1)
        for _ in range(5):
            await robot.get_firmware_version()
        assert robot.stats.sequence_gaps == 1


@pytest.mark.parametrize("scheme", ["shared", "per-id"])
async def test_the_simulator_numbers_frames_either_way(scheme: Any) -> None:
    async with (
        ChassisSimulator(ChassisSpec(sequence=scheme)) as sim,
        Chassis(sim.port) as robot,
    ):
        await robot.enable_power_telemetry(True)
        async with robot.power() as power:
            for _ in range(10):
                await anext(power)
                await robot.get_firmware_version()
        assert robot.sequence_scheme == scheme
        assert robot.stats.sequence_gaps == 0
