"""What ``chassis-sdk plot`` draws, checked on the figure itself: m/s and rad/s on their
own axes, the wheel pairs told apart, the path from odometry, commanded against
measured when the capture holds commands, and no panel left silently empty."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib  # the `plot` extra (in `all`): missing, these tests fail, not skip
import pytest

from chassis_sdk.cli import main as cli_main
from chassis_sdk.cli.devices import commands as device_commands
from chassis_sdk.devices import profile
from chassis_sdk.devices.board.protocol import velocity_command as board_velocity
from chassis_sdk.devices.chassis.protocol import velocity_command
from chassis_sdk.protocol import BoardEncoder, ChassisEncoder
from chassis_sdk.recording import capture
from chassis_sdk.recording.columns import decode_columns
from chassis_sdk.sim import BoardFirmware, ChassisFirmware

matplotlib.use("Agg")
from matplotlib.figure import Figure


def data(line: Any) -> tuple[list[float], list[float]]:
    """A plotted line's points as plain floats."""
    return [float(x) for x in line.get_xdata()], [float(y) for y in line.get_ydata()]


def write_capture(path: Path, chunks: list[tuple[float, bytes]]) -> None:
    lines = [json.dumps({"capture": 1, "port": "test", "started": "2026-11-23T00:00:00"})]
    lines += [json.dumps({"t": t, "data": data.hex()}) for t, data in chunks]
    path.write_text("\n".join(lines) + "\n")


def chassis_session() -> list[tuple[float, bytes]]:
    """Two seconds of a chassis turning on a tap that sees both directions."""
    fw, enc = ChassisFirmware(), ChassisEncoder()
    fw.on_connect(0.0)
    chunks = []
    for step in range(200):
        t = step * 0.01
        if step % 5 == 0:
            command = enc.encode(velocity_command(0.4, 0.8 if t < 1.0 else -0.8))
            fw.receive(command, t)
            chunks.append((t, command))
        out = fw.poll(t)
        if out:
            chunks.append((t, out))
    return chunks


def test_the_chassis_plot_separates_units_wheels_and_commands(tmp_path: Path) -> None:
    path = tmp_path / "chassis.jsonl"
    write_capture(path, chassis_session())
    rows = capture.capture_columns(path, "chassis")
    commands = capture.capture_columns(path, "chassis", commands=True)
    assert len(commands.messages) == 40
    fig = Figure()
    plot = device_commands("chassis").plot
    assert plot is not None
    plot(rows, commands, fig)
    linear, angular, wheels, volts, path_ax = fig.axes
    assert (linear.get_ylabel(), angular.get_ylabel()) == ("linear (m/s)", "angular (rad/s)")
    assert [line.get_label() for line in linear.get_lines()] == ["measured", "commanded"]
    _, commanded = data(angular.get_lines()[1])
    assert sorted({round(c, 5) for c in commanded}) == [-0.8, 0.8]  # float32 on the wire
    styles = {
        line.get_label(): (line.get_color(), line.get_linestyle()) for line in wheels.get_lines()
    }
    assert len(set(styles.values())) == 4  # every wheel told apart
    assert styles["front_left"][0] == styles["rear_left"][0] != styles["front_right"][0]
    assert volts.get_lines()
    assert path_ax.get_aspect() == 1.0
    xs, ys = data(path_ax.get_lines()[0])
    assert max(xs) > 0.2  # it drove forward
    assert max(ys) > 0.05  # and turned left first


def test_the_board_plot_says_why_the_battery_panel_is_empty() -> None:
    fw, enc = BoardFirmware(), BoardEncoder()
    fw.on_connect(0.0)
    received: list[tuple[float, bytes]] = []
    sent: list[tuple[float, bytes]] = []
    for step in range(100):
        t = step * 0.01
        if step % 10 == 0:
            frame = enc.encode(board_velocity(0.3, 0.5))
            fw.receive(frame, t)
            sent.append((t, frame))
        received.append((t, fw.poll(t)))
    rows = decode_columns(received, profile("board").codec.decoder())
    commands = decode_columns(sent, profile("board").codec.command_decoder())
    assert len(commands.messages) == 10
    plot = device_commands("board").plot
    assert plot is not None
    with_battery = Figure()
    plot(rows, commands, with_battery)
    assert with_battery.axes[2].get_lines()  # the battery panel
    without = Figure()
    del rows.tables["BatteryReading"]
    plot(rows, commands, without)
    battery_panel = without.axes[2]
    assert not battery_panel.get_lines()
    assert "no battery reading" in battery_panel.texts[0].get_text()
    angular = with_battery.axes[1]
    assert [line.get_label() for line in angular.get_lines()] == ["measured", "commanded", "gyro z"]


def test_plot_on_the_command_line_counts_the_commands(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "chassis.jsonl"
    write_capture(path, chassis_session())
    png = tmp_path / "out.png"
    assert cli_main(["plot", str(path), "-o", str(png)]) == 0
    assert "and 40 commands" in capsys.readouterr().out
    assert png.stat().st_size > 10_000
