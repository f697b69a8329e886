"""MCAP recordings, CSV export, replay of MCAP, and the live Foxglove server: against
the simulators over real ptys, read back with the independent ``mcap`` reader and an
independent WebSocket client (tests/support/foxglove_client.py)."""

from __future__ import annotations

import asyncio
import csv
import itertools
import json
import signal
from pathlib import Path

import pytest
from mcap.reader import make_reader

from chassis_sdk import Board, Chassis, EventKind, Telemetry
from chassis_sdk.core.plain import json_schema
from chassis_sdk.integrations.foxglove import FoxgloveServer
from chassis_sdk.protocol import DockingState, DriveVelocity
from chassis_sdk.recording import capture
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import ROOT, cli, running
from .support.foxglove_client import FoxgloveClient
from .support.helpers import kill_while_recording, until

pytestmark = [pytest.mark.surface, pytest.mark.timeout(60)]


def summary(path: Path) -> tuple[dict[str, tuple[str, str, str, int]], dict[str, dict[str, str]]]:
    """topic -> (message encoding, schema name, schema encoding, count); metadata."""
    with path.open("rb") as f:
        reader = make_reader(f)
        s = reader.get_summary()
        assert s is not None
        assert s.statistics is not None
        channels = {}
        for cid, ch in s.channels.items():
            schema = s.schemas[ch.schema_id]
            count = s.statistics.channel_message_counts.get(cid, 0)
            channels[ch.topic] = (ch.message_encoding, schema.name, schema.encoding, count)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return channels, metadata


def messages(path: Path, topic: str) -> list[tuple[int, bytes]]:
    with path.open("rb") as f:
        return [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


async def all_received(sim: ChassisSimulator, path: Path) -> list[object]:
    """What the simulator received, once it has read every frame the recording says
    was written (the zero of ``close()`` is written as the device closes, and the
    simulator reads it a loop turn or more later)."""
    sent = sum(1 for _ in capture.decode_capture(path, "chassis", commands=True))
    async with asyncio.timeout(5.0):
        while len(sim.firmware.received) < sent:
            await asyncio.sleep(0)  # checked once per loop iteration
    return [c for _, c in sim.firmware.received]


async def telemetry_frames(robot: Chassis, n: int) -> list[Telemetry]:
    frames = []
    async for t in robot.telemetry():
        frames.append(t)
        if len(frames) == n:
            break
    return frames


# --- recording from the application ------------------------------------------------------


@pytest.mark.integration
async def test_an_application_recording_holds_both_directions_streams_and_metadata(
    tmp_path: Path,
) -> None:
    path = tmp_path / "run.mcap"
    async with ChassisSimulator() as sim:
        port = sim.port
        async with Chassis(sim.port, record=path) as robot:
            assert robot.recording == path
            await robot.enable_power_telemetry()
            await robot.set_velocity(0.3, 0.2)
            await telemetry_frames(robot, 20)
            sim.firmware.press_bumper()
            async for event in robot.events():
                if event.kind is EventKind.BUMPER_HIT:
                    break
            version = await robot.get_firmware_version()
            seen = await telemetry_frames(robot, 5)
        written = await all_received(sim, path)
    channels, metadata = summary(path)
    expect = {
        "/chassis/raw/rx": ("json", "chassis_sdk.RawBytes", "jsonschema"),
        "/chassis/raw/tx": ("json", "chassis_sdk.RawBytes", "jsonschema"),
        "/chassis/commands": ("json", "chassis_sdk.chassis.Command", "jsonschema"),
        "/chassis/telemetry": ("json", "chassis_sdk.chassis.Telemetry", "jsonschema"),
        "/chassis/power": ("json", "chassis_sdk.chassis.PowerTelemetry", "jsonschema"),
        "/chassis/odometry": ("json", "chassis_sdk.chassis.Odometry", "jsonschema"),
        "/chassis/events": ("json", "chassis_sdk.chassis.RobotEvent", "jsonschema"),
        "/chassis/link": ("json", "chassis_sdk.LinkState", "jsonschema"),
        "/chassis/pose": ("protobuf", "foxglove.PoseInFrame", "protobuf"),
        "/tf": ("protobuf", "foxglove.FrameTransforms", "protobuf"),
        "/chassis/log": ("protobuf", "foxglove.Log", "protobuf"),
    }
    for topic, (encoding, schema, schema_encoding) in expect.items():
        assert topic in channels, (topic, sorted(channels))
        assert channels[topic][:3] == (encoding, schema, schema_encoding), topic
        assert channels[topic][3] > 0, topic
    # Every decoded message is the raw bytes decoded again: the file re-decodes.
    redecoded = [m for _, m in capture.decode_capture(path, "chassis") if isinstance(m, Telemetry)]
    telemetry = [json.loads(d) for _, d in messages(path, "/chassis/telemetry")]
    assert [t["seq"] for t in telemetry] == [t.seq for t in redecoded]
    # All the application saw, then the robot coming to rest after the final zero
    # (the recording goes on until it is still: issue 44, item 6).
    assert seen[-1].seq in [t["seq"] for t in telemetry]
    assert telemetry[-1]["linear"] == 0.0
    assert channels["/chassis/odometry"][3] == channels["/chassis/pose"][3]
    assert channels["/chassis/pose"][3] == channels["/tf"][3]
    # Both directions: every frame the simulator received is in raw/tx, decoded too,
    # the watchdog's resends and the zero of close() included (the last one).
    sent = [c for _, c in capture.decode_capture(path, "chassis", commands=True)]
    assert sent == written
    assert channels["/chassis/commands"][3] == len(written)
    assert channels["/chassis/raw/tx"][3] == len(written)
    drives = [c for c in sent if isinstance(c, DriveVelocity)]
    assert drives[0].linear_mm == 300
    assert drives[0].angular == pytest.approx(0.2)
    assert drives[-1] == DriveVelocity(0, 0.0)
    commands = [json.loads(d) for _, d in messages(path, "/chassis/commands")]
    assert commands[-1] == {"type": "DriveVelocity", "linear_mm": 0, "angular": 0.0}
    assert version == 0x0103 or version > 0
    events = [json.loads(d) for _, d in messages(path, "/chassis/events")]
    assert {"kind": "BUMPER_HIT", "source": "front"}.items() <= events[0].items()
    states = [json.loads(d)["state"] for _, d in messages(path, "/chassis/link")]
    assert states[0] in ("disconnected", "connecting")
    assert "connected" in states
    assert states[-1] == "disconnected"
    info = metadata["chassis_sdk"]
    assert info["device"] == "chassis"
    assert info["port"] == port
    assert info["baudrate"] == "115200"
    assert info["sdk_version"]
    assert info["transport"] in ("pyserial-asyncio", "pyserial-asyncio-fast", "serialx")
    # Receive times: the raw bytes are stamped when they arrived, 50 Hz apart.
    rx = messages(path, "/chassis/raw/rx")
    assert all(b >= a for (a, _), (b, _) in itertools.pairwise(rx))
    span = (rx[-1][0] - rx[0][0]) / 1e9
    assert 0.3 < span < 10


@pytest.mark.integration
async def test_a_board_recording_has_its_own_topics(tmp_path: Path) -> None:
    path = tmp_path / "board.mcap"
    async with BoardSimulator() as sim, Board(sim.port, record=path) as board:
        async for _ in board.imu():
            break
        await board.set_velocity(0.2, 0.0)
        async for _ in board.velocity():
            break
    channels, metadata = summary(path)
    assert channels["/board/imu"][1] == "chassis_sdk.board.ImuSample"
    assert channels["/board/imu"][3] > 0
    assert channels["/board/commands"][3] > 0
    assert metadata["chassis_sdk"]["device"] == "board"


@pytest.mark.integration
async def test_a_jsonl_recording_holds_both_directions(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    async with ChassisSimulator() as sim:
        async with Chassis(sim.port, record=path) as robot:
            await robot.set_velocity(0.1, 0.0)
            await telemetry_frames(robot, 10)
        written = await all_received(sim, path)
    assert [c for _, c in capture.decode_capture(path, "chassis", commands=True)] == written
    received = [m for _, m in capture.decode_capture(path, "chassis")]
    assert sum(isinstance(m, Telemetry) for m in received) >= 10


def test_a_bad_record_option_is_refused_before_anything_opens(tmp_path: Path) -> None:
    for bad in (tmp_path, "", 3, b"run.mcap"):
        with pytest.raises(ValueError, match="record must be a file path"):
            Chassis("/dev/null", record=bad)  # type: ignore[arg-type]
    assert not list(tmp_path.iterdir())


@pytest.mark.integration
async def test_a_hard_kill_leaves_a_file_readable_up_to_the_last_second(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    async with ChassisSimulator() as sim:
        await kill_while_recording(sim.port, str(path), "sys.argv[2]", ROOT)
        killed_at = len(sim.firmware.received)
    # 100 frames took 2 s; chunks are flushed every second: at least one is whole.
    frames = [m for _, m in capture.decode_capture(path, "chassis") if isinstance(m, Telemetry)]
    assert len(frames) >= 40
    sent = list(capture.decode_capture(path, "chassis", commands=True))
    assert 0 < len(sent) <= killed_at
    code, out, err = await cli("replay", str(path))
    assert code == 0, err
    assert "Telemetry: " in out


# --- the CLI: record .mcap, replay, export, plot ------------------------------------------


@pytest.mark.integration
async def test_cli_records_mcap_and_replays_and_exports_it(tmp_path: Path) -> None:
    path = tmp_path / "cli.mcap"
    async with ChassisSimulator() as sim:
        code, out, err = await cli("record", sim.port, str(path), "--seconds", "1.5")
        assert code == 0, err
    channels, metadata = summary(path)
    assert metadata["chassis_sdk"]["device"] == "chassis"  # heard on the port
    n = channels["/chassis/telemetry"][3]
    assert n >= 50
    assert channels["/chassis/odometry"][3] == n
    assert "/chassis/raw/tx" not in channels or channels["/chassis/raw/tx"][3] == 0
    code, out, err = await cli("replay", str(path), "--json")
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert sum(line["type"] == "Telemetry" for line in lines) == n
    code, out, err = await cli("export", str(path), "--csv", str(tmp_path / "csv"))
    assert code == 0, err
    with (tmp_path / "csv" / "telemetry.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == n
    assert {"t", "voltage", "status", "wheels.front_left", "seq"} <= set(rows[0])
    assert f"{n:,} rows (telemetry)" in out
    with (tmp_path / "csv" / "odometry.csv").open() as f:
        assert len(list(csv.DictReader(f))) == n


@pytest.mark.integration
async def test_export_writes_commands_of_an_application_recording(tmp_path: Path) -> None:
    from chassis_sdk.recording.export import export_csv

    path = tmp_path / "app.jsonl"
    async with ChassisSimulator() as sim, Chassis(sim.port, record=path) as robot:
        await robot.set_velocity(0.25, 0.0)
        await telemetry_frames(robot, 10)
    written = export_csv(path, tmp_path / "out", "chassis")
    assert written["commands_DriveVelocity"].rows >= 2
    with written["commands_DriveVelocity"].path.open() as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["linear_mm"] == "250"
    assert rows[-1]["linear_mm"] == "0"
    assert written["telemetry"].rows >= 10


@pytest.mark.integration
async def test_export_has_a_column_for_every_field_even_one_the_first_row_leaves_out(
    tmp_path: Path,
) -> None:
    # An event's fields that are None are left out of its JSON, not of its CSV: the
    # first event (a bumper: no state) still gives the docking change its column.
    from chassis_sdk.recording.export import export_csv

    path = tmp_path / "events.jsonl"
    async with ChassisSimulator() as sim, Chassis(sim.port, record=path) as robot:
        events = robot.events()
        sim.firmware.press_bumper()
        async for event in events:
            if event.kind is EventKind.BUMPER_HIT:
                await robot.start_docking()
            elif event.kind is EventKind.DOCKING_CHANGED:
                break
    written = export_csv(path, tmp_path / "out", "chassis")
    with written["events"].path.open() as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert reader.fieldnames is not None
    assert reader.fieldnames[:8] == [
        "t", "kind", "source", "timestamp", "state", "voltage", "percentage", "action"
    ]  # fmt: skip
    assert rows[0]["kind"] == "BUMPER_HIT"
    assert rows[0]["state"] == ""
    docking = next(r for r in rows if r["kind"] == "DOCKING_CHANGED")
    assert docking["state"] in {s.name for s in DockingState}


def test_json_schemas_describe_what_plain_writes() -> None:
    schema = json_schema(Telemetry)
    assert schema["type"] == "object"
    props = schema["properties"]
    assert props["voltage"] == {"type": "number"}
    assert props["seq"] == {"type": "integer"}
    assert props["status"] == {"type": "string"}  # flags by name: "A|B", "" for none
    assert props["docking"] == {"type": "string"}  # by name (UNKNOWN_<n> if unlisted)
    assert set(schema["required"]) == set(props)  # no field of a Telemetry is ever None
    assert props["wheels"]["properties"]["front_left"] == {"type": "number"}


# --- live: the Foxglove WebSocket server ---------------------------------------------------


def _twist(linear: float, angular: float) -> bytes:
    return json.dumps({"linear": {"x": linear}, "angular": {"z": angular}}).encode()


async def _moving(sim: ChassisSimulator, moving: bool, timeout: float) -> float:
    """Seconds until the simulated wheels' targets are (not) zero."""
    return await until(lambda: any(sim.firmware.target) == moving, timeout)


@pytest.mark.integration
@pytest.mark.timing
async def test_foxglove_client_sees_streams_calls_services_and_drives(tmp_path: Path) -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, command_timeout=0.3) as robot,
        FoxgloveServer(robot, port=0, record=tmp_path / "live.mcap") as server,
        FoxgloveClient(server.url) as client,
    ):
        assert server.url.startswith("ws://127.0.0.1:")
        await client.wait_for(lambda: "/chassis/telemetry" in client.channels)
        assert client.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
        assert {"clientPublish", "services"} <= set(client.server_info["capabilities"])
        await client.wait_for(lambda: {"/chassis/pose", "/tf"} <= set(client.channels))
        # Each advertisement is a message of its own: wait for the services' as well
        # (through the front they can arrive a loop turn after the channels').
        await client.wait_for(lambda: len(client.services) == 4)
        assert client.channels["/chassis/telemetry"]["encoding"] == "json"
        assert client.channels["/chassis/pose"]["schemaName"] == "foxglove.PoseInFrame"
        assert set(client.services) == {
            "stop",
            "emergency_stop",
            "release_emergency_stop",
            "clear_faults",
        }
        # Telemetry at the device's rate (50 Hz).
        await client.subscribe("/chassis/telemetry", "/chassis/link")
        await client.wait_for(lambda: len(client.received["/chassis/telemetry"]) >= 1)
        first = client.received["/chassis/telemetry"][0][0]
        await client.wait_for(lambda: len(client.received["/chassis/telemetry"]) >= 51)
        last = client.received["/chassis/telemetry"][50][0]
        rate = 50 / ((last - first) / 1e9)
        assert 40 < rate < 60, rate
        seqs = [m["seq"] for m in client.messages("/chassis/telemetry")]
        assert seqs == sorted(seqs)
        # Teleop: published velocity moves the robot ...
        await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")
        await client.publish(1, _twist(0.3, 0.0))
        await _moving(sim, True, 2.0)
        assert robot.commanded_velocity == (0.3, 0.0)
        for _ in range(5):  # ... keeps it moving while the panel publishes ...
            await client.publish(1, _twist(0.3, 0.0))
            await asyncio.sleep(0.1)
        assert any(sim.firmware.target)
        # ... and the deadman stops it within command_timeout of the last message.
        stopped_after = await _moving(sim, False, 2.0)
        assert stopped_after < 0.3 + 0.2, stopped_after
        # The stop service stops at once.
        await client.publish(1, _twist(0.2, 0.0))
        await _moving(sim, True, 2.0)
        # A service returns once its frame is handed to the port; the simulator reads
        # it on a later turn of the loop (how many depends on the loop: uvloop's differ).
        assert await client.call("stop") == {"success": True, "message": "done"}
        assert await _moving(sim, False, 0.2) < 0.2  # well before the 0.3 s deadman
        # E-stop and its release, through the services.
        assert (await client.call("emergency_stop"))["success"]
        await until(lambda: sim.firmware.software_estop, 1.0)
        assert (await client.call("release_emergency_stop"))["success"]
        await until(lambda: not sim.firmware.software_estop, 1.0)
        assert (await client.call("clear_faults"))["success"]
        # Releasing the e-stop restarts nothing: the client streams, so it must send a
        # zero (neutral) before it drives again (the joystick rule).
        await client.publish(1, _twist(0.2, 0.0))
        await until(lambda: server.rejected == 1, 1.0)
        assert not any(sim.firmware.target)
        await client.publish(1, _twist(0.0, 0.0))
        await client.publish(1, _twist(0.2, 0.0))
        await _moving(sim, True, 2.0)
        # The panel going away stops the robot at once, not at the deadman.
        await client.unadvertise(1)
        assert await _moving(sim, False, 0.2) < 0.2
        assert server.commands >= 9
        assert server.rejected == 1
        assert any("neutral" in s["message"] for s in client.statuses)
    channels, _ = summary(tmp_path / "live.mcap")
    assert channels["/chassis/telemetry"][3] >= 50
    assert channels["/chassis/commands"][3] > 0


@pytest.mark.integration
@pytest.mark.parametrize(
    "payload",
    [
        b"not json",
        b"[1, 2]",
        b'{"linear": {"x": "fast"}, "angular": {"z": 0}}',
        b'{"linear": {"x": 1e999}, "angular": {"z": 0}}',
        b'{"linear": 5, "angular": {"z": 0}}',
        b'{"linear": {"x": true}}',
        b'{"linear": {"x": 1e9}, "angular": {"z": 0}}',  # past the wire field
    ],
)
async def test_a_bad_velocity_message_is_rejected_and_reported_never_acted_on(
    payload: bytes,
) -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        FoxgloveServer(robot, port=0) as server,
        FoxgloveClient(server.url) as client,
    ):
        await client.wait_for(lambda: bool(client.server_info))
        await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")
        await client.publish(1, payload)
        await client.wait_for(lambda: bool(client.statuses))
        assert client.statuses[0]["level"] == 1  # warning
        assert "velocity" in client.statuses[0]["message"]
        assert server.rejected == 1
        assert server.commands == 0
        assert robot.commanded_velocity is None
        assert not any(isinstance(c, DriveVelocity) for _, c in sim.firmware.received)


@pytest.mark.integration
async def test_read_only_takes_no_velocity_and_offers_only_stops() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        FoxgloveServer(robot, port=0, read_only=True) as server,
        FoxgloveClient(server.url) as client,
    ):
        await client.wait_for(lambda: bool(client.services))
        assert "clientPublish" not in client.server_info["capabilities"]
        assert set(client.services) == {"stop", "emergency_stop"}


@pytest.mark.integration
async def test_cli_serve_end_to_end_and_sigterm_stops_the_robot() -> None:
    async with ChassisSimulator() as sim:
        async with running("serve", sim.port, "--foxglove-port", "0") as serve:
            line = await serve.wait_for_line(lambda line: "serving" in line)
            url = line.split(" at ")[1].split()[0]
            async with FoxgloveClient(url) as client:
                await client.wait_for(lambda: "/chassis/telemetry" in client.channels)
                await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")
                for _ in range(20):  # keep it going until the signal
                    await client.publish(1, _twist(0.9, 0.0))  # past --max-linear 0.5
                    if any(sim.firmware.target):
                        break
                    await asyncio.sleep(0.05)
                drives = [c for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]
                assert drives
                assert drives[-1].linear_mm == 500  # clamped by the limit
                serve.proc.send_signal(signal.SIGTERM)
                code, _, err = await serve.finish()
        assert code == 128 + signal.SIGTERM, err
        last = [c for _, c in sim.firmware.received if isinstance(c, DriveVelocity)][-1]
        assert last == DriveVelocity(0, 0.0)


@pytest.mark.integration
async def test_cli_serve_says_when_the_port_is_taken() -> None:
    taken = await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0)
    port = taken.sockets[0].getsockname()[1]
    try:
        async with ChassisSimulator() as sim:
            code, _, err = await cli("serve", sim.port, "--foxglove-port", str(port))
    finally:
        taken.close()
    assert code == 1
    assert err.strip().startswith("chassis-sdk: cannot serve on 127.0.0.1:"), err


@pytest.mark.integration
async def test_a_recording_goes_on_through_an_unplug(tmp_path: Path) -> None:
    from chassis_sdk import ConnectionState

    path = tmp_path / "unplug.mcap"
    async with ChassisSimulator() as sim, Chassis(sim.port, reconnect=True, record=path) as robot:
        before = await telemetry_frames(robot, 5)
        states = robot.connection_states()
        sim.unplug()
        async for state in states:
            if state is ConnectionState.RECONNECTING:
                break
        await sim.replug()
        await robot.wait_connected(timeout=5)
        after = await telemetry_frames(robot, 5)
    link = [json.loads(d)["state"] for _, d in messages(path, "/chassis/link")]
    assert link.index("reconnecting") < len(link) - 1 - link[::-1].index("connected")
    seqs = [json.loads(d)["seq"] for _, d in messages(path, "/chassis/telemetry")]
    assert before[0].seq in seqs
    assert after[-1].seq in seqs


@pytest.mark.integration
async def test_a_recording_holds_the_loss_of_a_link_that_does_not_come_back(
    tmp_path: Path,
) -> None:
    from chassis_sdk import ConnectionLostError

    path = tmp_path / "lost.mcap"
    async with ChassisSimulator() as sim:
        robot = Chassis(sim.port, record=path)
        async with robot:
            await telemetry_frames(robot, 3)
            sim.unplug()
            with pytest.raises(ConnectionLostError):
                async for _ in robot.telemetry():
                    pass
    link = [json.loads(d)["state"] for _, d in messages(path, "/chassis/link")]
    assert link[-2:] == ["lost", "disconnected"]
    events = [json.loads(d)["kind"] for _, d in messages(path, "/chassis/events")]
    assert "LINK_LOST" in events


@pytest.mark.integration
async def test_the_application_runs_before_the_recorder_logs_its_frame(tmp_path: Path) -> None:
    """The control path never waits for the recorder: when the application's task
    wakes for a frame, that frame's recording work is still queued."""
    async with ChassisSimulator() as sim, Chassis(sim.port, record=tmp_path / "o.mcap") as robot:
        sink = robot._recording.sink  # type: ignore[union-attr]
        queued = []
        n = 0
        async for t in robot.telemetry():
            queued.append(any(args and args[0] is t for _, args in sink._after._pending))
            n += 1
            if n == 20:
                break
    assert all(queued), queued
