"""Every JSON schema the SDK writes is one the viewers read, and every message it writes
matches its schema: the rules of tests/support/viewers.py (Lichtblick's
``parseJsonSchema``, Ajv's and JSON Schema's) over each message type's schema, over
every schema of an MCAP recording of each device and of the live Foxglove server, and
``jsonschema`` over every message they carry."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from chassis_sdk import BatteryModel, Board, Chassis, EventKind, Telemetry
from chassis_sdk.core.events import Measure, RobotEvent
from chassis_sdk.core.odometry import Odometry
from chassis_sdk.core.plain import json_schema, jsonable
from chassis_sdk.devices.board.messages import (
    BatteryReading,
    ImuCounts,
    ImuSample,
    Vector3,
    VelocityFeedback,
)
from chassis_sdk.devices.chassis.messages import (
    ChassisStatus,
    DockingState,
    PowerTelemetry,
    WheelCurrents,
    WheelSpeeds,
)
from chassis_sdk.integrations.foxglove import FoxgloveServer
from chassis_sdk.sim import BoardSimulator, ChassisSimulator, ChassisSpec, PackSpec

from .support.foxglove_client import FoxgloveClient
from .support.helpers import until
from .support.toy_device import ToyTelemetry
from .support.viewers import message_problems, schema_problems

pytestmark = pytest.mark.timeout(60)

_V = Vector3(0.1, -0.2, 9.8)
#: A message of every type a stream carries, in each of its shapes (a field set or
#: not, flags none, one, several or undocumented, every event kind with its fields).
MESSAGES: list[object] = [
    Telemetry(25.6, ChassisStatus.REMOTE_OFFLINE, DockingState.SEARCHING, 0.3, 0.1,
              WheelSpeeds(0.3, 0.3, 0.3, 0.3), 7, 12.5),
    Telemetry(25.6, ChassisStatus(0), DockingState.DOCKED, 0.0, 0.0, WheelSpeeds(0, 0, 0, 0)),
    Telemetry(24.0, ChassisStatus.HARDWARE_ESTOP | ChassisStatus.FRONT_BUMPER,
              DockingState.ERROR, 0.0, 0.0, WheelSpeeds(0, 0, 0, 0)),
    Telemetry(24.0, ChassisStatus(1 << 20 | 1), DockingState(9), 0.0, 0.0,
              WheelSpeeds(0, 0, 0, 0)),  # a state the document does not list: UNKNOWN_9
    PowerTelemetry(WheelCurrents(1.0, 1.1, 1.2, 1.3), 25.1, 25.2, 3, 1.0),
    Odometry(1.0, -0.5, 0.7, 0.3, 0.1, 2.0),
    ImuSample(_V, _V, _V, 1.0, ImuCounts(1, 2, 3, 4, 5, 6, 7, 8, 9)),
    ImuSample(_V, _V, _V, 1.0),
    VelocityFeedback(0.2, 0.1, 1.0),
    BatteryReading(12.1, 1.0),
    ToyTelemetry(0.5, 12.0, 1.0),
    *(RobotEvent(kind, "front", 3.0) for kind in EventKind),
    RobotEvent(EventKind.DOCKING_CHANGED, "", 3.0, state=DockingState.DOCKED),
    RobotEvent(EventKind.BATTERY_LOW, "", 3.0, voltage=22.1),
    RobotEvent(EventKind.BATTERY_CRITICAL, "", 3.0, voltage=21.0, percentage=4.5),
    RobotEvent(EventKind.REFLEX, "tilt", 3.0, action="stop", values=(Measure("tilt", 31.2),)),
    RobotEvent(EventKind.SAFETY_OVERRIDDEN, "battery", 3.0, action="ignore"),
]  # fmt: skip


def _schema(msg: object) -> dict[str, Any]:
    schema = json_schema(type(msg))
    assert schema.get("type") == "object", schema
    return schema


TYPES: list[type] = sorted({type(m) for m in MESSAGES}, key=lambda t: t.__name__)


@pytest.mark.parametrize("tp", TYPES, ids=lambda t: t.__name__)
def test_every_message_type_has_a_schema_the_viewers_read(tp: type) -> None:
    assert schema_problems(json_schema(tp), tp.__name__) == []


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_every_message_matches_its_own_schema(msg: object) -> None:
    data = json.dumps(jsonable(msg))
    assert message_problems(_schema(msg), data) == [], data


def test_a_docking_change_matches_the_event_schema_and_names_its_state() -> None:
    event = RobotEvent(EventKind.DOCKING_CHANGED, "", 3.0, state=DockingState.CONTACT)
    schema = json_schema(RobotEvent)
    assert schema_problems(schema, "RobotEvent") == []
    body = jsonable(event)
    assert message_problems(schema, json.dumps(body)) == []
    assert body["kind"] == "DOCKING_CHANGED"
    assert body["state"] == "CONTACT"


def test_enums_and_flags_are_written_by_name_as_strings() -> None:
    # One type a property: a string, whatever the value (no number for "none" or for
    # an undocumented bit, which is named BIT_n).
    props = json_schema(Telemetry)["properties"]
    assert props["status"] == {"type": "string"}
    # DockingState names a state it does not know UNKNOWN_<n>: no closed list of names.
    assert props["docking"] == {"type": "string"}
    event = json_schema(RobotEvent)["properties"]["kind"]
    assert event == {"type": "string", "enum": [k.name for k in EventKind]}
    wheels = WheelSpeeds(0, 0, 0, 0)
    status = [
        jsonable(Telemetry(25.0, s, DockingState.DOCKED, 0.0, 0.0, wheels))["status"]
        for s in (
            ChassisStatus(0),
            ChassisStatus.REMOTE_OFFLINE,
            ChassisStatus.HARDWARE_ESTOP | ChassisStatus.FRONT_BUMPER,
            ChassisStatus(1 << 20 | 1),
        )
    ]
    assert status == ["", "REMOTE_OFFLINE", "HARDWARE_ESTOP|FRONT_BUMPER", "HARDWARE_ESTOP|BIT_20"]


def test_an_optional_field_is_left_out_rather_than_null() -> None:
    event = json.loads(json.dumps(jsonable(RobotEvent(EventKind.BUMPER_HIT, "front", 3.0))))
    assert event == {"kind": "BUMPER_HIT", "source": "front", "timestamp": 3.0, "values": []}
    schema = json_schema(RobotEvent)
    assert schema["properties"]["voltage"] == {"type": "number"}
    assert set(schema["required"]) == {"kind", "source", "timestamp", "values"}
    imu = json_schema(ImuSample)
    assert imu["properties"]["raw"]["type"] == "object"
    assert "raw" not in imu["required"]
    assert "raw" not in jsonable(ImuSample(_V, _V, _V, 1.0))


# --- what a recording and the live server write ----------------------------------------------


def _mcap_channels(path: Path) -> dict[str, tuple[str, dict[str, Any], list[bytes]]]:
    """topic -> (schema name, JSON schema, messages) of every JSON channel."""
    out: dict[str, tuple[str, dict[str, Any], list[bytes]]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "json":
                continue
            assert schema is not None, channel.topic
            assert schema.encoding == "jsonschema", channel.topic
            entry = out.setdefault(channel.topic, (schema.name, json.loads(schema.data), []))
            entry[2].append(message.data)
    return out


def _check_channels(channels: dict[str, tuple[str, dict[str, Any], list[bytes]]]) -> None:
    problems = []
    for topic, (name, schema, messages) in channels.items():
        problems += [f"{topic}: {p}" for p in schema_problems(schema, name)]
        for data in messages:
            problems += [f"{topic}: {p} in {data[:200]!r}" for p in message_problems(schema, data)]
    assert problems == []


#: The events a chassis recording waits for: a state, a source, a voltage and a charge.
WANTED = {EventKind.DOCKING_CHANGED, EventKind.BUMPER_HIT, EventKind.BATTERY_LOW}


@pytest.mark.integration
async def test_every_schema_and_message_of_a_chassis_recording_is_one_viewers_read(
    tmp_path: Path,
) -> None:
    path = tmp_path / "chassis.mcap"
    spec = ChassisSpec(pack=PackSpec("li-ion", cells=7, charge=8.0))
    model = BatteryModel("li-ion", cells=7, warmup=0.2, min_readings=2)
    kinds: set[EventKind] = set()
    async with (
        ChassisSimulator(spec) as sim,
        Chassis(sim.port, record=path, battery=model) as robot,
    ):
        events = robot.events()
        await robot.enable_power_telemetry()
        await robot.set_velocity(0.2, 0.1)
        await robot.start_docking()
        sim.firmware.press_bumper()
        await robot.emergency_stop()
        async with asyncio.timeout(10):
            async for event in events:
                kinds.add(event.kind)
                if kinds >= WANTED:
                    break
        await until(lambda: robot.battery_percentage is not None)
        await robot.release_emergency_stop()
        await robot.stop()
    channels = _mcap_channels(path)
    for stream in ("telemetry", "power", "odometry", "events", "commands", "link", "raw/rx"):
        assert f"/chassis/{stream}" in channels
    _check_channels(channels)
    recorded = [json.loads(d) for d in channels["/chassis/events"][2]]
    docking = next(e for e in recorded if e["kind"] == "DOCKING_CHANGED")
    assert docking["state"] in {s.name for s in DockingState}
    telemetry = [json.loads(d) for d in channels["/chassis/telemetry"][2]]
    assert "battery_percentage" not in telemetry[0]  # not known yet: left out
    assert any(isinstance(t.get("battery_percentage"), float) for t in telemetry)


@pytest.mark.integration
async def test_every_schema_and_message_of_a_board_recording_is_one_viewers_read(
    tmp_path: Path,
) -> None:
    path = tmp_path / "board.mcap"
    async with BoardSimulator() as sim, Board(sim.port, record=path) as board:
        await board.set_velocity(0.2, 0.1)
        await board.set_led(True)
        await until(lambda: board.latest_imu is not None and board.latest_battery is not None)
        await asyncio.sleep(0.2)
    channels = _mcap_channels(path)
    for stream in ("imu", "velocity", "battery", "odometry", "commands", "link"):
        assert f"/board/{stream}" in channels
    _check_channels(channels)


@pytest.mark.integration
@pytest.mark.surface
async def test_every_schema_the_live_server_advertises_is_one_viewers_read() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        FoxgloveServer(robot, port=0) as server,
        FoxgloveClient(server.url) as client,
    ):
        await client.wait_for(
            lambda: {"/chassis/telemetry", "/chassis/link"} <= set(client.channels)
        )
        await client.wait_for(lambda: len(client.services) == 4)
        await robot.start_docking()  # a docking change: the events channel
        await client.wait_for(lambda: "/chassis/events" in client.channels)
        await client.subscribe("/chassis/telemetry", "/chassis/events")
        sim.firmware.press_bumper()
        await client.wait_for(lambda: bool(client.received["/chassis/events"]))
        await client.wait_for(lambda: len(client.received["/chassis/telemetry"]) >= 3)
        problems = []
        for topic, channel in client.channels.items():
            if channel["encoding"] != "json":
                continue
            assert channel["schemaEncoding"] == "jsonschema", topic
            schema = json.loads(channel["schema"])
            problems += [f"{topic}: {p}" for p in schema_problems(schema, channel["schemaName"])]
            for _, data in client.received[topic]:
                problems += [f"{topic}: {p}" for p in message_problems(schema, data)]
        for name, service in client.services.items():
            for part in ("request", "response"):
                spec = service[part]
                assert spec["schemaEncoding"] == "jsonschema", (name, part)
                schema = json.loads(spec["schema"])
                problems += [f"service {name} {part}: {p}" for p in schema_problems(schema)]
        assert problems == []
