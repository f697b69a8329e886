"""The MQTT bridge against a real mosquitto on loopback and the simulators on ptys:
the connection topic and last will, retained info, telemetry at the rate and events
(stamped in wall time), commands under the deadman, broker loss, no late command,
malformed payloads, read-only mode, MQTT 5 request/response, and the fleet console."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import ssl
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiomqtt
import pytest

from chassis_sdk import BatteryModel, Board, Chassis, EventKind
from chassis_sdk.integrations.mqtt import MqttBridge
from chassis_sdk.protocol import DockingState, DriveVelocity
from chassis_sdk.sim import BoardSimulator, ChassisSimulator, ChassisSpec, PackSpec

from .support.cli import ROOT
from .support.helpers import drives, until
from .support.mqtt import Observer, bridge_client, bridged, request
from .support.mqtt_broker import Broker, broker


@pytest.fixture
async def stand() -> AsyncIterator[tuple[Broker, ChassisSimulator, Chassis, Observer]]:
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port, reconnect=True) as robot,
        Observer(b) as obs,
    ):
        yield b, sim, robot, obs


@pytest.mark.integration
@pytest.mark.mqtt
async def test_connection_info_link_and_a_clean_stop(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, _sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/info")) and bool(obs.on("robots/r1/link")))
        assert obs.on("robots/r1/connection")[-1]["state"] == "ONLINE"
        info = obs.on("robots/r1/info")[-1]
        assert info["device"] == "chassis"
        assert info["hardware_version"] == "ZKWL-brush-motor-chassis"
        assert info["chassis_info"]["track_width"] == pytest.approx(0.725)
        assert info["features"]["wheels"] == 4
        assert obs.on("robots/r1/link")[-1]["state"] == "connected"
    await obs.wait(lambda: obs.on("robots/r1/connection")[-1]["state"] == "OFFLINE")
    # Retained: a dashboard that comes later still learns all three.
    async with Observer(b) as late:
        await late.wait(lambda: len({t for t, _, r in late.seen if r}) >= 3)
        assert late.on("robots/r1/connection")[-1]["state"] == "OFFLINE"
        assert late.on("robots/r1/info")[-1]["device"] == "chassis"


@pytest.mark.integration
@pytest.mark.mqtt
@pytest.mark.timing
async def test_telemetry_at_the_rate_and_events(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot, rate=10.0):
        await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
        start, first = time.monotonic(), len(obs.on("robots/r1/telemetry/telemetry"))
        await asyncio.sleep(1.5)
        rate = (len(obs.on("robots/r1/telemetry/telemetry")) - first) / (time.monotonic() - start)
        assert 8.0 <= rate <= 11.0  # at most 10/s of the 50 Hz stream, never a backlog
        t = obs.on("robots/r1/telemetry/telemetry")[-1]
        assert (t["type"], t["status"], t["docking"]) == (
            "Telemetry",
            "REMOTE_OFFLINE",
            "SEARCHING",
        )
        assert obs.on("robots/r1/telemetry/odometry")[-1]["type"] == "Odometry"
        sim.firmware.press_bumper(front=True)
        await obs.wait(lambda: any(e["kind"] == "BUMPER_HIT" for e in obs.on("robots/r1/events")))
        hit = next(e for e in obs.on("robots/r1/events") if e["kind"] == "BUMPER_HIT")
        assert hit["source"] == "front"


@pytest.mark.integration
@pytest.mark.mqtt
async def test_events_on_mqtt_are_the_json_a_recording_writes(tmp_path: Path) -> None:
    # One encoding: an event on MQTT is the MCAP's JSON of it (kind by name, as
    # docs/mqtt.md says; the state of a docking change by name), but for the clock: its
    # timestamp is wall time and the recording's monotonic reading is `monotonic`.
    from mcap.reader import make_reader

    path = tmp_path / "run.mcap"
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Observer(b) as obs,
        Chassis(sim.port, record=path) as robot,
        bridged(b, robot),
    ):
        await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
        sim.firmware.press_bumper(front=True)
        await robot.start_docking()
        await obs.wait(
            lambda: (
                {"BUMPER_HIT", "DOCKING_CHANGED"} <= {e["kind"] for e in obs.on("robots/r1/events")}
            )
        )
    published = obs.on("robots/r1/events")
    with path.open("rb") as f:
        recorded = [
            json.loads(m.data)
            for _, _, m in make_reader(f).iter_messages(topics=["/chassis/events"])
        ]
    # Each by its clock reading and its fields (a frame can make two events).
    written = [(e.pop("timestamp"), e) for e in recorded]
    for event in published:
        assert event["kind"] in {k.name for k in EventKind}, event
        clock = event.pop("monotonic")
        del event["timestamp"]
        assert (clock, event) in written
    docking = next(e for e in published if e["kind"] == "DOCKING_CHANGED")
    assert docking["state"] in {s.name for s in DockingState}


@pytest.mark.integration
@pytest.mark.mqtt
async def test_mqtt_telemetry_and_events_are_stamped_in_wall_time() -> None:
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port, reconnect=True) as robot,
        Observer(b) as obs,
        bridged(b, robot, rate=10.0),
    ):
        await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
        sim.firmware.press_bumper(front=True)
        await obs.wait(lambda: bool(obs.on("robots/r1/events")))
        telemetry = obs.on("robots/r1/telemetry/telemetry")[-1]
        event = obs.on("robots/r1/events")[-1]
    for body in (telemetry, event):
        assert abs(body["timestamp"] - time.time()) < 30
        assert "monotonic" in body


@pytest.mark.integration
@pytest.mark.mqtt
@pytest.mark.timing
async def test_a_velocity_command_moves_the_robot_and_stops_when_commands_stop(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        for _ in range(6):
            await obs.publish("robots/r1/cmd/velocity", {"linear": 0.3, "angular": 0.1})
            await asyncio.sleep(0.1)
        await until(lambda: any(d.linear_mm == 300 for d in drives(sim)))
        stopped_publishing = time.monotonic()
        await until(lambda: drives(sim)[-1] == DriveVelocity(0, 0.0), timeout=2.0)
        # The deadman (command_timeout 0.5 s) stopped it: the dashboard went quiet.
        assert time.monotonic() - stopped_publishing < 1.0
        assert robot.stats.command_expiries == 1
        await obs.publish("robots/r1/cmd/velocity", {"linear": 0.2, "angular": 0.0})
        await until(lambda: drives(sim)[-1].linear_mm == 200)
        await obs.publish("robots/r1/cmd/stop", b"")
        await until(lambda: drives(sim)[-1] == DriveVelocity(0, 0.0))
        await obs.publish("robots/r1/cmd/estop", {"engaged": True})
        await until(
            lambda: robot.latest_telemetry is not None and robot.latest_telemetry.emergency_stopped
        )


@pytest.mark.integration
@pytest.mark.mqtt
@pytest.mark.timing
async def test_losing_the_broker_stops_the_robot_at_once(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    task = asyncio.create_task(MqttBridge(robot, bridge_client(b, "r1"), "r1").run())
    await obs.wait(lambda: bool(obs.on("robots/r1/connection")))

    async def dashboard() -> None:  # keeps the command fresh, as a joystick would
        with contextlib.suppress(aiomqtt.MqttError):
            while True:
                await obs.publish("robots/r1/cmd/velocity", {"linear": 0.3, "angular": 0.0})
                await asyncio.sleep(0.05)

    joystick = asyncio.create_task(dashboard())
    await until(lambda: any(d.linear_mm == 300 for d in drives(sim)))
    killed = time.monotonic()
    b.kill()
    with pytest.raises(aiomqtt.MqttError):
        await asyncio.wait_for(task, 5)
    await until(lambda: drives(sim)[-1] == DriveVelocity(0, 0.0), timeout=1.0)
    # At once: well before the deadman's 0.5 s after the last command would have.
    assert time.monotonic() - killed < 0.3
    assert robot.commanded_velocity is None
    joystick.cancel()


@pytest.mark.integration
@pytest.mark.mqtt
async def test_no_command_is_delivered_late_after_a_reconnect(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
    await obs.wait(lambda: obs.on("robots/r1/connection")[-1]["state"] == "OFFLINE")
    # While the bridge is away: commands at QoS 0 and 1, and one retained.
    await obs.publish("robots/r1/cmd/velocity", {"linear": 0.4, "angular": 0.0}, qos=1)
    await obs.publish("robots/r1/cmd/velocity", {"linear": 0.4, "angular": 0.0}, qos=0)
    await obs.publish("robots/r1/cmd/velocity", {"linear": 0.5, "angular": 0.0}, qos=1, retain=True)
    before = len(drives(sim))
    async with bridged(b, robot):
        await obs.wait(lambda: any("retained" in e["error"] for e in obs.on("robots/r1/errors")))
        await obs.wait(lambda: len(obs.on("robots/r1/telemetry/telemetry")) >= 5)
        assert all(d.linear_mm == 0 for d in drives(sim)[before:])
    await obs.publish("robots/r1/cmd/velocity", b"", retain=True)  # clear the retained one


@pytest.mark.integration
@pytest.mark.mqtt
@pytest.mark.parametrize(
    ("topic", "payload", "why"),
    [
        pytest.param("velocity", b"not json", "not JSON", id="not-json"),
        pytest.param("velocity", b"[1, 2]", "not an object", id="not-an-object"),
        pytest.param("velocity", b'{"linear": 0.3}', "'angular' must be a number", id="missing-field"),
        pytest.param("velocity", b'{"linear": "fast", "angular": 0}', "'linear' must be a number", id="a-string"),
        pytest.param("velocity", b'{"linear": true, "angular": 0}', "'linear' must be a number", id="a-bool"),
        pytest.param("velocity", b'{"linear": NaN, "angular": 0}', "NaN is not JSON", id="nan"),
        pytest.param("velocity", b'{"linear": 1e999, "angular": 0}', "'linear' must be finite", id="infinite"),
        pytest.param("velocity", b'{"linear": 1e9, "angular": 0}', "out of range", id="out-of-range"),
        pytest.param("velocity", b'{"linear": 0, "angular": 99}', "angular", id="angular-too-fast"),
        pytest.param("estop", b'{"engaged": "yes"}', "'engaged' must be true or false", id="estop-not-bool"),
        pytest.param("fly", b"{}", "unknown command 'fly'", id="unknown-command"),
    ],
)  # fmt: skip
async def test_malformed_commands_are_rejected_and_never_written(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer], topic: str, payload: bytes, why: str
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        await obs.publish(f"robots/r1/cmd/{topic}", payload)
        await obs.wait(lambda: bool(obs.on("robots/r1/errors")))
        error = obs.on("robots/r1/errors")[0]
        assert error["topic"] == f"robots/r1/cmd/{topic}"
        assert why in error["error"]
        assert drives(sim) == []
        assert robot.is_connected


@pytest.mark.integration
@pytest.mark.mqtt
async def test_read_only_never_takes_a_command_but_answers_requests(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, sim, robot, obs = stand
    async with bridged(b, robot, read_only=True):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        await obs.publish("robots/r1/cmd/velocity", {"linear": 0.3, "angular": 0.0})
        result = await request(obs, "r1", "get_firmware_version")  # the bridge is past it
        assert result == {"result": sim.firmware.spec.firmware_version}
        assert drives(sim) == []
        assert obs.on("robots/r1/errors") == []


@pytest.mark.integration
@pytest.mark.mqtt
async def test_requests_and_responses_over_mqtt5(
    stand: tuple[Broker, ChassisSimulator, Chassis, Observer],
) -> None:
    b, _sim, robot, obs = stand
    async with bridged(b, robot):
        await obs.wait(lambda: bool(obs.on("robots/r1/connection")))
        assert (await request(obs, "r1", "get_chassis_info"))["result"][
            "wheelbase"
        ] == pytest.approx(0.5)
        # The status word comes with telemetry: diagnose once the first has arrived (the
        # open flushes what the port held, so it may not have yet).
        await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
        report = (await request(obs, "r1", "diagnose"))["result"]
        assert report["device"] == "chassis"
        assert "status REMOTE_OFFLINE" in report["notes"]
        assert (
            "unknown request 'set_velocity'" in (await request(obs, "r1", "set_velocity"))["error"]
        )


@pytest.mark.integration
@pytest.mark.mqtt
async def test_a_board_is_bridged_with_its_own_streams() -> None:
    async with (
        broker() as b,
        BoardSimulator() as sim,
        Board(sim.port) as board,
        Observer(b) as obs,
        bridged(b, board, "b1"),
    ):
        await obs.wait(lambda: bool(obs.on("robots/b1/telemetry/imu")))
        info = obs.on("robots/b1/info")[-1]
        assert (info["device"], info["features"]["servos"]) == ("board", 2)
        await obs.wait(lambda: bool(obs.on("robots/b1/telemetry/battery")))
        await obs.publish("robots/b1/cmd/estop", {"engaged": True})
        await obs.wait(lambda: bool(obs.on("robots/b1/errors")))
        assert "a board has no e-stop; it was stopped" in obs.on("robots/b1/errors")[0]["error"]


@pytest.mark.integration
@pytest.mark.mqtt
async def test_the_state_of_charge_beside_the_voltage_once_known_and_its_events() -> None:
    # A pack at 5 %: left out while the model warms up (3 s), then the charge, CRITICAL,
    # and BATTERY_LOW then BATTERY_CRITICAL on events with their percentage.
    pack = PackSpec("li-ion", cells=7, charge=5.0)
    model = BatteryModel("li-ion", cells=7, warmup=3.0, min_readings=3)
    async with broker() as b, Observer(b) as obs, ChassisSimulator(ChassisSpec(pack=pack)) as sim:
        async with Chassis(sim.port, battery=model) as robot, bridged(b, robot, rate=10.0):
            topic = "robots/r1/telemetry/telemetry"
            await obs.wait(
                lambda: any(e["kind"] == "BATTERY_CRITICAL" for e in obs.on("robots/r1/events")),
                timeout=10.0,
            )
            await obs.wait(lambda: "battery_percentage" in obs.on(topic)[-1])
            truth = sim.firmware.battery_charge
        frames = obs.on(topic)
        # Unknown: left out (never null, never a number).
        assert "battery_percentage" not in frames[0]
        assert "battery_level" not in frames[0]
        known = [f for f in frames if "battery_percentage" in f]
        assert all(0.0 <= f["battery_percentage"] <= 100.0 for f in known)
        assert truth is not None
        assert abs(known[-1]["battery_percentage"] - truth) <= 3
        assert known[-1]["battery_level"] == "CRITICAL"
        events = [e for e in obs.on("robots/r1/events") if e["kind"].startswith("BATTERY")]
        assert [e["kind"] for e in events] == ["BATTERY_LOW", "BATTERY_CRITICAL"]
        assert all(e["percentage"] < model.critical and e["voltage"] > 0 for e in events)
    async with (  # a board's battery stream; no model: the voltage alone
        broker() as b,
        BoardSimulator() as board_sim,
        Board(board_sim.port) as board,
        Observer(b) as obs,
        bridged(b, board, "b1"),
    ):
        await obs.wait(lambda: bool(obs.on("robots/b1/telemetry/battery")))
        reading = obs.on("robots/b1/telemetry/battery")[-1]
        assert reading["voltage"] > 0
        assert "battery_percentage" not in reading
        assert "battery_level" not in reading
        assert "battery_percentage" not in obs.on("robots/b1/telemetry/imu")[-1]


@pytest.mark.integration
@pytest.mark.mqtt
async def test_the_last_will_says_connectionbroken_when_the_bridge_vanishes() -> None:
    async with broker() as b, ChassisSimulator() as sim, Observer(b) as obs:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "chassis_sdk.cli", "bridge", sim.port,
            "--broker", f"mqtt://127.0.0.1:{b.port}", "--robot-id", "r9",
            cwd=ROOT, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            await obs.wait(lambda: bool(obs.on("robots/r9/info")), timeout=15)
            assert obs.on("robots/r9/connection")[-1]["state"] == "ONLINE"
            os.kill(proc.pid, signal.SIGKILL)
            await obs.wait(
                lambda: obs.on("robots/r9/connection")[-1]["state"] == "CONNECTIONBROKEN"
            )
        finally:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()


@pytest.mark.integration
@pytest.mark.mqtt
async def test_the_fleet_console_lists_every_robot_and_stops_them_all() -> None:
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        BoardSimulator() as board_sim,
        Board(board_sim.port) as board,
        Observer(b) as obs,
        bridged(b, robot, "r1"),
        bridged(b, board, "b2"),
    ):
        await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
        await obs.wait(lambda: bool(obs.on("robots/b2/telemetry/battery")))
        await robot.set_velocity(0.3, 0.0, duration=30.0)  # moving until stopped
        proc = await asyncio.create_subprocess_exec(
            sys.executable, str(ROOT / "examples" / "fleet_console.py"),
            "--broker", f"mqtt://127.0.0.1:{b.port}", "--seconds", "1.5", "--stop-all",
            cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out, err = await asyncio.wait_for(proc.communicate(), 20)
        text = out.decode()
        assert proc.returncode == 0, err.decode()
        lines = {line.split()[0]: line for line in text.splitlines()[1:] if line.strip()}
        assert "chassis  ONLINE            connected     27." in lines["r1"]
        assert "board    ONLINE            connected     " in lines["b2"]
        assert "sent cmd/stop to 2 robot(s)" in text
        await until(lambda: drives(sim)[-1] == DriveVelocity(0, 0.0))
        assert robot.commanded_velocity is None


@pytest.mark.integration
async def test_the_fleet_console_without_a_broker_is_one_line() -> None:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(ROOT / "examples" / "fleet_console.py"),
        "--broker", "mqtt://127.0.0.1:1", "--seconds", "0.5",
        cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    _, err = await asyncio.wait_for(proc.communicate(), 20)
    assert proc.returncode == 1
    lines = err.decode().strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("fleet_console.py: broker mqtt://127.0.0.1:1:")


@pytest.fixture
def tls_files(tmp_path: Path) -> Path:
    """A self-signed certificate for 127.0.0.1 and a password file (r1, dashboard)."""
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
         "-keyout", str(tmp_path / "key.pem"), "-out", str(tmp_path / "cert.pem"),
         "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1"],
        check=True, capture_output=True,
    )  # fmt: skip
    users = tmp_path / "passwd"
    for user, password in (("r1", "secret-r1"), ("dashboard", "secret-d")):
        flags = ["-b"] if users.exists() else ["-b", "-c"]
        subprocess.run(["mosquitto_passwd", *flags, str(users), user, password], check=True)
    return tmp_path


@pytest.mark.integration
@pytest.mark.mqtt
async def test_the_bridge_command_logs_in_over_tls_and_says_when_it_cannot(
    tls_files: Path,
) -> None:
    tmp_path = tls_files
    key, cert, users = tmp_path / "key.pem", tmp_path / "cert.pem", tmp_path / "passwd"
    right, wrong = tmp_path / "right", tmp_path / "wrong"
    right.write_text("secret-r1\n")
    wrong.write_text("guess\n")
    right.chmod(0o600)  # a password file others may read is refused
    wrong.chmod(0o600)
    extra = (
        f"cafile {cert}\ncertfile {cert}\nkeyfile {key}\n"
        f"allow_anonymous false\npassword_file {users}\n"
    )
    tls = ssl.create_default_context(cafile=str(cert))
    async with (
        broker(extra) as b,
        ChassisSimulator() as sim,
        ChassisSimulator() as other,
        Observer(b, username="dashboard", password="secret-d", tls_context=tls) as obs,
    ):
        url = f"mqtts://127.0.0.1:{b.port}"
        common = ["--cafile", str(cert), "--username", "r1"]
        good = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "chassis_sdk.cli", "bridge", sim.port, "--broker", url,
            "--robot-id", "r1", "--password-file", str(right), *common,
            cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        bad = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "chassis_sdk.cli", "bridge", other.port, "--broker", url,
            "--robot-id", "r2", "--password-file", str(wrong), *common,
            cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            await obs.wait(lambda: bool(obs.on("robots/r1/info")), timeout=15)
            assert bad.stdout is not None
            async with asyncio.timeout(15):
                while True:
                    line = (await bad.stdout.readline()).decode()
                    if line.startswith("broker "):
                        break
            assert "the robot is stopped; retrying in" in line
            assert obs.on("robots/r2/connection") == []
        finally:
            for proc in (good, bad):
                proc.send_signal(signal.SIGTERM)
                await proc.wait()
        await obs.wait(lambda: obs.on("robots/r1/connection")[-1]["state"] == "OFFLINE")


@pytest.mark.integration
@pytest.mark.mqtt
async def test_the_fleet_console_shows_an_offline_robots_link_as_unknown_as_the_docs_do() -> None:
    async with broker() as b, ChassisSimulator() as sim, Chassis(sim.port) as robot:
        async with Observer(b) as obs:
            async with bridged(b, robot, "r2"):
                await obs.wait(lambda: bool(obs.on("robots/r2/link")))
            await obs.wait(lambda: obs.on("robots/r2/connection")[-1]["state"] == "OFFLINE")
        proc = await asyncio.create_subprocess_exec(
            sys.executable, str(ROOT / "examples" / "fleet_console.py"),
            "--broker", f"mqtt://127.0.0.1:{b.port}", "--seconds", "1",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        async with asyncio.timeout(20):
            out, err = await proc.communicate()
    assert proc.returncode == 0, err.decode()
    header, line = out.decode().splitlines()[:2]
    assert line.split() == ["r2", "chassis", "OFFLINE", "unknown", "-"]
    docs = (ROOT / "docs" / "mqtt.md").read_text()
    block = docs[docs.index("$ python examples/fleet_console.py") :].splitlines()
    assert block[1] == header
    assert block[3].split() == ["r2", "chassis", "OFFLINE", "unknown", "-"]


def test_bridges_spread_their_telemetry_slots_over_the_period() -> None:
    """Bridges started together must not publish in one burst every period (a command
    arriving then waited behind all of them: p99 6-11 ms at 50 robots in one process):
    each topic has its own place in the period, the same every time."""
    from chassis_sdk.integrations.mqtt.publish import PHASES, slot_phase

    phases = [slot_phase(f"robots/r{i}", 0.1) for i in range(50)]
    assert len(set(phases)) == PHASES
    assert all(0 <= phase < 0.1 for phase in phases)
    # No instant holds much more than its share of a fleet.
    assert max(phases.count(phase) for phase in phases) <= 2 * 50 // PHASES
    assert slot_phase("robots/r7", 0.1) == slot_phase("robots/r7", 0.1)
