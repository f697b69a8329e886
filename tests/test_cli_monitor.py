"""The ``monitor`` command: the real ``chassis-sdk`` in a subprocess against the
simulators. A viewer writes nothing, not even a zero; it shows the charge of the
profile's battery; its JSON is stamped in wall time; a board's monitor is a live view
with units; each status bit is explained once, where it first shows. The rows named
are those of issue 28, which asked for them."""

from __future__ import annotations

import json
import time
from pathlib import Path

from chassis_sdk.sim import ChassisSimulator

from .support.cli import ROOT, cli

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
        assert '"battery_percentage": null' not in last
        code, out, err = await cli(
            "monitor", sim.port, "--json", "--seconds", "0.5", cwd=tmp_path,
            env={"PYTHONPATH": str(ROOT)},
        )  # fmt: skip
        assert code == 0, err
        assert '"battery_percentage": null' in out.splitlines()[-1]


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


# --- row 24: what the status means, and the firmware as versions are written ------------


async def test_monitor_explains_each_status_bit_once_where_it_first_shows() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("monitor", sim.port, "--seconds", "1")
    assert code == 0, err
    assert out.count("(status REMOTE_OFFLINE: the remote control is off") == 1
