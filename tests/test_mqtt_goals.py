"""Goals over MQTT against a real mosquitto on loopback and the simulated chassis on a
pty: ``request/move|turn|goto`` runs one and answers when it ends, its progress goes out
on ``goal``, ``cmd/cancel`` stops it at once, bad payloads are refused and never acted
on, and a read-only bridge refuses them."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator

import pytest

from chassis_sdk import Chassis
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.helpers import drives, until
from .support.mqtt import Observer, bridged, request
from .support.mqtt_broker import Broker, broker

pytestmark = [pytest.mark.integration, pytest.mark.mqtt]


@pytest.fixture
async def stand() -> AsyncIterator[tuple[Broker, ChassisSimulator, Chassis, Observer]]:
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        Observer(b) as obs,
    ):
        yield b, sim, robot, obs


async def test_a_move_request_answers_with_its_result_and_reports_progress(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        answer = await request(obs, "r1", "move", {"distance": 0.3, "timeout": 10}, timeout=15)
        result = answer["result"]
        assert result["ended"] == "done"
        assert abs(result["error"]) <= 0.01
        assert result["pose"]["x"] == pytest.approx(0.3, abs=0.01)
        states = [p["state"] for p in obs.on("robots/r1/goal")]
        assert states[0] == "active"
        assert states[-1] == "done"
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)
        turned = await request(obs, "r1", "turn", {"angle": math.pi / 4}, timeout=15)
        assert abs(turned["result"]["error"]) <= math.radians(1)


async def test_cancel_stops_the_goal_at_once(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        pending = asyncio.create_task(request(obs, "r1", "goto", {"x": 3.0, "y": 0.0}, timeout=15))
        await until(lambda: any(d.linear_mm > 0 for d in drives(sim)))
        await obs.publish("robots/r1/cmd/cancel", {})
        answer = await pending
        assert answer == {"error": "cancelled"}
        await until(lambda: drives(sim)[-1] == DriveVelocity(0, 0.0), 1.0)
        assert obs.on("robots/r1/goal")[-1] == {"goal": "goto", "state": "cancelled"}


@pytest.mark.parametrize(
    ("name", "payload", "says"),
    [
        ("move", {}, "move needs 'distance'"),
        ("move", {"distance": "far"}, "distance"),
        ("turn", {"angle": 1.0, "speed": 2.0}, "unknown field 'speed'"),
        ("goto", b"not json", "JSON"),
    ],
)
async def test_a_bad_goal_is_refused_and_never_acted_on(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
    name: str,
    payload: object,
    says: str,
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        with pytest.raises(TimeoutError):
            await request(obs, "r1", name, payload, timeout=0.5)
        await obs.wait(lambda: bool(obs.on("robots/r1/errors")))
        assert says in str(obs.on("robots/r1/errors")[-1])
        assert drives(sim) == []


async def test_a_read_only_bridge_refuses_goals(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot, read_only=True):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        with pytest.raises(TimeoutError):
            await request(obs, "r1", "move", {"distance": 1.0}, timeout=0.5)
        await obs.wait(lambda: bool(obs.on("robots/r1/errors")))
        assert "read-only" in str(obs.on("robots/r1/errors")[-1])
        assert drives(sim) == []
