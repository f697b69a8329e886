"""Issue 28's rough edges that are not a single command's: each row a test that runs
what the new user ran and checks what they expected."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import sys
import time
from pathlib import Path

import pytest

from chassis_sdk.core.ports import command_line, lock_holder
from chassis_sdk.sim import ChassisSimulator
from tests.support.cli import silent_pty
from tests.support.helpers import until

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = Path(sys.executable).with_name("chassis-sdk")


# --- row 14: who holds the port, in words that say what it is ---------------------------


@pytest.mark.parametrize(
    ("argv", "shown"),
    [
        (
            ["/srv/venv/bin/python3", "/srv/venv/bin/chassis-sdk", "monitor", "/dev/x"],
            "chassis-sdk monitor /dev/x",
        ),
        (
            ["/usr/bin/python3.11", "-u", "-m", "chassis_sdk.cli", "record", "p"],
            "chassis_sdk.cli record p",
        ),
        (["/usr/bin/minicom", "-D", "/dev/ttyUSB0"], "minicom -D /dev/ttyUSB0"),
        ([], ""),
    ],
)
def test_command_line_keeps_the_program_and_its_arguments(argv: list[str], shown: str) -> None:
    assert command_line(argv) == shown


def test_a_long_command_line_is_cut_and_marked() -> None:
    shown = command_line(["tool", *["argument"] * 20])
    assert len(shown) == 80
    assert shown.startswith("tool argument")
    assert shown.endswith("…")


@pytest.mark.skipif(not SCRIPT.exists(), reason="needs the installed chassis-sdk script")
async def test_info_on_a_port_monitor_holds_names_monitor_and_its_subcommand() -> None:
    async with ChassisSimulator() as sim:
        port = sim.port
        monitor = await asyncio.create_subprocess_exec(
            str(SCRIPT), "monitor", sim.port, "--json", stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
        )  # fmt: skip
        try:
            await until(lambda: lock_holder(sim.port) is not None, timeout=15)
            info = await asyncio.create_subprocess_exec(
                str(SCRIPT), "info", sim.port, stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            async with asyncio.timeout(30):
                _, err = await info.communicate()
        finally:
            monitor.terminate()
            await monitor.wait()
    lines = err.decode().strip().splitlines()
    assert info.returncode != 0
    assert len(lines) == 1, lines
    assert f"held by process {monitor.pid} (chassis-sdk monitor {port} --json)" in lines[0]
    assert os.sep + "python" not in lines[0]


# --- row 16: a viewer never writes -------------------------------------------------------


async def cli(*args: str, cwd: Path = ROOT) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "chassis_sdk.cli", *args, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE, cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    async with asyncio.timeout(60):
        out, err = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


async def test_monitor_writes_no_frame_at_all_not_even_the_zero_at_close() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--json", "--seconds", "0.5")
        assert code == 0, err
        assert '"type": "Telemetry"' in out
        assert sim.firmware.received == type(sim.firmware.received)()


async def test_monitor_shows_the_charge_of_the_profiles_battery(tmp_path: Path) -> None:
    profile = tmp_path / "robot.toml"
    profile.write_text(
        "[battery]\nchemistry = 'lifepo4'\ncells = 8\nwarmup = 0.2\nmin_readings = 1\n"
    )
    async with ChassisSimulator() as sim:
        code, out, err = await cli(
            "--config", str(profile), "monitor", sim.port, "--json", "--seconds", "1.5"
        )
        assert code == 0, err
        last = [line for line in out.splitlines() if '"type": "Telemetry"' in line][-1]
        assert '"battery_percentage": null' not in last
        code, out, err = await cli("monitor", sim.port, "--json", "--seconds", "0.5", cwd=tmp_path)
        assert code == 0, err
        assert '"battery_percentage": null' in out.splitlines()[-1]


# --- row 7: one clock in everything that leaves the process ------------------------------


def test_outbound_json_carries_wall_time_and_names_the_monotonic_reading() -> None:
    from chassis_sdk.core.events import EventKind, RobotEvent
    from chassis_sdk.core.plain import outbound

    now = time.monotonic()
    body = outbound(RobotEvent(EventKind.BUMPER_HIT, source="front", timestamp=now - 2.0))
    assert body["monotonic"] == now - 2.0
    assert abs(body["timestamp"] - (time.time() - 2.0)) < 0.5
    assert "monotonic" not in outbound({"value": 1})


async def test_monitor_json_stamps_are_wall_time() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--json", "--seconds", "0.5")
    assert code == 0, err
    frames = [json.loads(line) for line in out.splitlines() if '"type": "Telemetry"' in line]
    assert frames
    for frame in frames:
        assert abs(frame["timestamp"] - time.time()) < 30
        assert frame["monotonic"] < frame["timestamp"] / 1000  # seconds since boot, named so


async def test_mqtt_telemetry_and_events_are_stamped_in_wall_time() -> None:
    pytest.importorskip("aiomqtt")
    from chassis_sdk import Chassis
    from tests.support.mqtt import Observer, bridged
    from tests.support.mqtt_broker import broker, find_mosquitto

    if find_mosquitto() is None:
        pytest.skip("needs mosquitto")
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


# --- row 21: the fleet console after the bridges stop ------------------------------------


async def test_the_fleet_console_shows_an_offline_robots_link_as_unknown_as_the_docs_do() -> None:
    pytest.importorskip("aiomqtt")
    from chassis_sdk import Chassis
    from tests.support.mqtt import Observer, bridged
    from tests.support.mqtt_broker import broker, find_mosquitto

    if find_mosquitto() is None:
        pytest.skip("needs mosquitto")
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


# --- row 8: a board's monitor is a live view with units ----------------------------------


async def test_board_monitor_piped_is_short_lines_with_units_and_the_link() -> None:
    from chassis_sdk.sim import BoardSimulator

    async with BoardSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--device", "board", "--seconds", "1")
        assert sim.firmware.received == type(sim.firmware.received)()  # a viewer writes nothing
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("link: connected via ")
    readings = [line for line in lines if line.startswith("v=")]
    assert len(readings) >= 3
    for line in readings:
        assert len(line) <= 100
        for unit in (" m/s", " rad/s", ") g", " deg/s"):
            assert unit in line, line
    assert any(line.endswith(" V") for line in readings)


async def test_board_monitor_json_and_its_table() -> None:
    from rich.console import Console

    from chassis_sdk import Board
    from chassis_sdk.cli.board import _View
    from chassis_sdk.sim import BoardSimulator

    async with BoardSimulator() as sim:
        code, out, err = await cli(
            "monitor", sim.port, "--device", "board", "--seconds", "1", "--json"
        )
        assert code == 0, err
        kinds = {json.loads(line)["type"] for line in out.splitlines()}
        assert {"ImuSample", "VelocityFeedback", "BatteryReading"} <= kinds
        async with Board(sim.port) as board:
            await anext(board.battery())
            await anext(board.imu())
            console = Console(width=120, record=True)
            console.print(_View(board, sim.port, as_json=False).render())
    text = console.export_text()
    for row in ("link", "velocity", "accel", "gyro", "battery", "counters"):
        assert f"│ {row}" in text, text
    assert "deg/s" in text
    assert " g " in text


# --- row 9: info on a noisy line says what it could read ---------------------------------


async def test_info_prints_every_field_it_read_marks_the_one_it_did_not_and_exits_partial() -> None:
    from chassis_sdk.protocol import CommandId

    async with ChassisSimulator() as sim:
        sim.firmware.ignored.add(CommandId.CHASSIS_INFO)  # as a line that loses each one
        code, out, err = await cli("info", sim.port, "--timeout", "0.2")
    assert code == 5, err
    assert "firmware     v1.0.3 (103)" in out
    assert "hardware     ZKWL-brush-motor-chassis" in out
    assert "geometry     (no reply: " in out
    assert "ship date    2024-01-02" in out
    assert "flags" in out  # the telemetry and the diagnosis still came
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "partial: no reply for geometry" in lines[0]


async def test_info_on_a_silent_port_still_fails_at_the_first_request() -> None:
    with silent_pty() as quiet:
        started = time.monotonic()
        code, _, err = await cli("info", quiet, "--timeout", "0.2")
        elapsed = time.monotonic() - started
    assert code == 2, err
    assert elapsed < 0.2 * 3 * 2 + 5  # one request's attempts, not four requests'


# --- row 24: what the status means, and the firmware as versions are written ------------


async def test_the_demo_explains_the_status_where_it_first_shows_it() -> None:
    code, out, err = await cli("demo")
    assert code == 0, err
    lines = out.splitlines()
    first = next(i for i, line in enumerate(lines) if "status=REMOTE_OFFLINE" in line)
    assert "REMOTE_OFFLINE: the remote control is off" in lines[first + 1]
    assert "normal under host control" in lines[first + 1]
    assert "firmware     v1.0.3 (103)" in out


async def test_monitor_explains_each_status_bit_once_where_it_first_shows() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--seconds", "1")
    assert code == 0, err
    assert out.count("(status REMOTE_OFFLINE: the remote control is off") == 1


# --- docs/cli.md's synopsis is what --help says ------------------------------------------


def synopsis(page: str) -> dict[str, str]:
    """Each command's lines in the synopsis block at the top of docs/cli.md."""
    block = page.split("```text\n", 1)[1].split("```", 1)[0]
    found: dict[str, str] = {}
    current = None
    for line in block.splitlines():
        if line.startswith("chassis-sdk "):
            current = line.split()[1]
            found[current] = found.get(current, "") + line.split("#", 1)[0]
        elif current is not None and line.startswith(" "):
            found[current] += " " + line.split("#", 1)[0]
    return found


def test_the_cli_synopsis_names_every_option_of_every_command() -> None:
    from chassis_sdk.cli import build_parser
    from chassis_sdk.cli.profile import subparsers

    # Said once for all in the text below the block: -h, -b/--baudrate and --config.
    everywhere = {"help", "baudrate", "config"}
    lines = synopsis((ROOT / "docs" / "cli.md").read_text())
    for name, parser in subparsers(build_parser()).items():
        assert name in lines, f"docs/cli.md's synopsis has no line for {name}"
        for action in parser._actions:
            skip = action.dest in everywhere or action.help == argparse.SUPPRESS
            if skip or not action.option_strings:
                continue
            said = [
                o for o in action.option_strings if re.search(rf"{re.escape(o)}\b", lines[name])
            ]
            assert said, (name, action.option_strings)


# --- row 18: a wrong type is a TypeError, a bad value a ValueError -----------------------


def test_wrong_types_are_type_errors_and_bad_values_value_errors() -> None:
    from chassis_sdk import Chassis
    from chassis_sdk.integrations.access import check_token
    from chassis_sdk.integrations.inbound import check_topic_level

    with pytest.raises(TypeError, match="port must be"):
        Chassis(5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="port must be"):
        Chassis("")
    with pytest.raises(TypeError, match="token must be a string"):
        check_token(12345678901234567890)
    with pytest.raises(ValueError, match="at least"):
        check_token("short")
    with pytest.raises(TypeError, match="robot_id must be a string"):
        check_topic_level(7, "robot_id")
    with pytest.raises(ValueError, match="letters, digits"):
        check_topic_level("a/b#", "robot_id")
