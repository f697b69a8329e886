"""The ``monitor`` command: the real ``chassis-sdk`` in a subprocess against the
simulators on ptys and TCP, a silent pty and the other device's simulator. A viewer
writes nothing, not even a zero; it lives through an unplug and says so; a silent port
or the other device is one line within seconds; its JSON is one object a line, stamped
in wall time; it shows the charge of the profile's battery; a board's monitor is a live
view with units, and any device gets one from its profile's streams; each status bit is
explained once, where it first shows. The rows named are those of issue 28, which
asked for them."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import ROOT, cli, one_line, running, silent_pty

pytestmark = pytest.mark.integration

# --- row 16: a viewer never writes -------------------------------------------------------


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
        assert '"battery_percentage": ' in last  # known: a number
        code, out, err = await cli(
            "monitor", sim.port, "--json", "--seconds", "0.5", cwd=tmp_path,
            env={"PYTHONPATH": str(ROOT)},
        )  # fmt: skip
        assert code == 0, err
        assert '"battery_percentage"' not in out.splitlines()[-1]  # no model: left out


# --- row 7: one clock in everything that leaves the process ------------------------------


async def test_monitor_json_stamps_are_wall_time() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--json", "--seconds", "0.5")
    assert code == 0, err
    frames = [json.loads(line) for line in out.splitlines() if '"type": "Telemetry"' in line]
    assert frames
    for frame in frames:
        assert abs(frame["timestamp"] - time.time()) < 30
        assert frame["monotonic"] < frame["timestamp"] / 1000  # seconds since boot, named so


# --- row 8: a board's monitor is a live view with units ----------------------------------


async def test_board_monitor_piped_is_short_lines_with_units_and_the_link() -> None:
    from chassis_sdk.sim import BoardSimulator

    async with BoardSimulator() as sim:
        # 2.5 s: the battery comes at 1 Hz, in whatever phase the command starts.
        code, out, err = await cli("monitor", sim.port, "--device", "board", "--seconds", "2.5")
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


# --- row 24: what the status means, and the firmware as versions are written ------------


async def test_monitor_explains_each_status_bit_once_where_it_first_shows() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--seconds", "1")
    assert code == 0, err
    assert out.count("(status REMOTE_OFFLINE: the remote control is off") == 1


# --- an unplug, a silent port or the other device, JSON, any device from its profile ------


@pytest.mark.slow
async def test_monitor_lives_through_an_unplug_and_says_so() -> None:
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        running("monitor", sim.port, "--seconds", "6") as mon,
    ):
        await mon.wait_for_line(lambda line: "v=+0.000" in line)
        sim.unplug()
        await mon.wait_for_line(lambda line: line == "link: reconnecting\n")
        await sim.replug()
        await mon.wait_for_line(lambda line: line == "link: connected\n")
        await mon.wait_for_line(lambda line: "v=+0.000" in line)
        code, out, err = await mon.finish()
    assert code == 0, err
    assert "Traceback" not in err
    assert "faults: none" in out


@pytest.mark.slow
async def test_monitor_on_a_silent_port_or_another_device_is_one_line_within_seconds() -> None:
    with silent_pty() as quiet:
        code, _, err = await cli("monitor", quiet, "--seconds", "30", timeout=10)
    assert code == 2
    assert "no 0x81 chassis telemetry from" in one_line(err)
    async with BoardSimulator() as board:
        code, _, err = await cli("monitor", board.port, "--seconds", "30", timeout=10)
    assert code == 1
    assert "none is a chassis frame: is it a board?" in one_line(err)


async def test_monitor_json_is_one_object_per_line() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--seconds", "1", "--json")
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    telemetry = [r for r in rows if r["type"] == "Telemetry"]
    assert len(telemetry) >= 20
    assert telemetry[0]["status"] == "REMOTE_OFFLINE"
    assert {"type": "faults", "faults": []} in rows


async def test_monitor_shows_any_device_from_its_profile_streams(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # A device with no monitor of its own gets the generic one: the board's, taken away.
    from chassis_sdk.cli import devices as device_commands
    from chassis_sdk.cli.monitor_command import monitor
    from chassis_sdk.devices import profile

    monkeypatch.delitem(device_commands.BUILTIN, "board")
    assert device_commands.commands("board").monitor is None
    async with BoardSimulator() as board:
        await monitor(profile("board"), board.port, 115200, 1.2, False)
        out = capsys.readouterr().out
        assert "imu: accel=" in out
        assert "velocity: linear=" in out
        lines = out.splitlines()
        assert len([line for line in lines if line.startswith("imu:")]) <= 8  # 5/s at most
        await monitor(profile("board"), board.port, 115200, 1.0, True)
        out = capsys.readouterr().out
    rows = [json.loads(line) for line in out.splitlines()]
    assert sum(r["type"] == "ImuSample" for r in rows) >= 50  # every sample at 100 Hz
    assert {"VelocityFeedback", "BatteryReading"} <= {r["type"] for r in rows}
