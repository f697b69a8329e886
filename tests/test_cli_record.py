"""Capturing a failure from the command line (issue 44, item 6): every command that
drives takes ``--record FILE`` (``record`` cannot run beside it: the port has one
owner); ``record`` runs until Ctrl-C unless ``--seconds``; a JSON-lines capture reaches
the disk at least once a second, so a hard kill leaves a capture; an empty file is
called empty; a recorded session goes on until the robot is still, so the stop is in
the file; ``replay`` prints the host's commands beside the device's messages.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import signal
from pathlib import Path

import pytest

from chassis_sdk import Chassis
from chassis_sdk.cli import build_parser
from chassis_sdk.cli.profile import subparsers
from chassis_sdk.protocol import DriveVelocity, Telemetry
from chassis_sdk.recording import capture
from chassis_sdk.recording.jsonl import FLUSH_INTERVAL
from chassis_sdk.sim import ChassisSimulator

from .support.cli import CLI, ROOT, cli, one_line, silent_pty

#: Every command that drives the robot: each takes --record FILE.
DRIVING = ["drive", "move", "turn", "goto", "teleop", "web", "serve", "ros2", "bridge", "calibrate"]


@pytest.mark.parametrize("command", DRIVING)
def test_every_command_that_drives_takes_record(command: str) -> None:
    parser = subparsers(build_parser())[command]
    options = {o for action in parser._actions for o in action.option_strings}
    assert "--record" in options


def test_record_runs_until_ctrl_c_unless_seconds_says_otherwise() -> None:
    args = build_parser().parse_args(["record", "/dev/ttyX", "run.jsonl"])
    assert args.seconds is None


def telemetry_and_commands(path: Path) -> tuple[list[tuple[float, Telemetry]], list[object]]:
    received = [
        (t, m) for t, m in capture.decode_capture(path, "chassis") if isinstance(m, Telemetry)
    ]
    sent = [m for _, m in capture.decode_capture(path, "chassis", commands=True)]
    return received, sent


@pytest.mark.integration
@pytest.mark.timing
@pytest.mark.parametrize("source", ["chassis", "silent"])
async def test_a_hard_kill_of_record_two_seconds_in_leaves_a_capture(
    tmp_path: Path, source: str
) -> None:
    path = tmp_path / "run.jsonl"
    async with contextlib.AsyncExitStack() as stack:
        if source == "chassis":
            port = (await stack.enter_async_context(ChassisSimulator())).port
        else:  # a port that says little: before, nothing at all reached the file
            port = stack.enter_context(silent_pty())
        proc = await asyncio.create_subprocess_exec(
            *CLI, "record", port, str(path), "--device", "chassis",
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL, cwd=ROOT,
        )  # fmt: skip
        try:
            async with asyncio.timeout(20):
                while not path.exists():  # the recorder has opened the port and the file
                    await asyncio.sleep(0.02)
            await asyncio.sleep(2.0)
        finally:
            proc.send_signal(signal.SIGKILL)
            await proc.wait()
    assert path.stat().st_size > 0
    received, _ = telemetry_and_commands(path)  # a capture: not "not a chassis-sdk capture"
    if source == "chassis":
        # At most the flush interval (and the kill's latency) is lost of the 2 s.
        assert received[-1][0] >= 2.0 - FLUSH_INTERVAL - 0.5


@pytest.mark.integration
@pytest.mark.timing
async def test_a_hard_kill_of_drive_record_keeps_what_it_sent_and_heard(tmp_path: Path) -> None:
    path = tmp_path / "drive.jsonl"
    async with ChassisSimulator() as sim:
        proc = await asyncio.create_subprocess_exec(
            *CLI, "drive", sim.port, "--linear", "0.1", "--duration", "30", "--record", str(path),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=ROOT,
        )  # fmt: skip
        assert proc.stdout is not None
        assert proc.stderr is not None
        try:
            async with asyncio.timeout(20):
                line = await proc.stdout.readline()
            assert line.startswith(b"driving"), (line, await proc.stderr.read())
            await asyncio.sleep(2.0)
        finally:
            proc.send_signal(signal.SIGKILL)
            await proc.wait()
    received, sent = telemetry_and_commands(path)
    assert received
    assert any(m.linear > 0.05 for _, m in received)
    assert any(isinstance(m, DriveVelocity) and m.linear_mm == 100 for m in sent)


@pytest.mark.integration
async def test_drive_record_holds_the_commands_and_the_robot_coming_to_rest(tmp_path: Path) -> None:
    path = tmp_path / "drive.jsonl"
    async with ChassisSimulator() as sim:
        code, _out, err = await cli(
            "drive", sim.port, "--linear", "0.4", "--duration", "0.6", "--record", str(path)
        )
    assert code == 0, err
    received, sent = telemetry_and_commands(path)
    assert any(isinstance(m, DriveVelocity) and m.linear_mm == 400 for m in sent)
    assert sent[-1] == DriveVelocity(0, 0.0)
    assert max(m.linear for _, m in received) > 0.3
    assert received[-1][1].linear == 0.0  # the stop, not only the command to stop


@pytest.mark.integration
@pytest.mark.parametrize("suffix", ["jsonl", "mcap"])
async def test_a_recorded_session_goes_on_until_the_robot_is_still(
    tmp_path: Path, suffix: str
) -> None:
    path = tmp_path / f"run.{suffix}"
    async with ChassisSimulator() as sim, Chassis(sim.port, record=path) as robot:
        async for t in robot.telemetry():
            await robot.set_velocity(0.5, 0.0)
            if t.linear >= 0.45:
                break
    received, _ = telemetry_and_commands(path)
    assert received[-1][1].linear == 0.0, received[-5:]


@pytest.mark.integration
@pytest.mark.parametrize("command", [("replay",), ("export", "--csv", "out"), ("plot",)])
async def test_an_empty_file_is_called_empty(tmp_path: Path, command: tuple[str, ...]) -> None:
    empty = tmp_path / "run.jsonl"
    empty.touch()
    code, _out, err = await cli(command[0], str(empty), *command[1:], cwd=tmp_path)
    assert code == 1, err
    assert one_line(err).startswith(f"chassis-sdk: {empty} is empty: no capture was written")


@pytest.mark.integration
async def test_a_capture_cut_in_the_middle_of_a_line_is_read_up_to_it(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    async with ChassisSimulator() as sim:
        await capture.record(sim.port, path, seconds=0.5, device="chassis")
    whole = path.read_text()
    path.write_text(whole[: len(whole) - 7])  # the kill came in the middle of the last line
    code, out, err = await cli("replay", str(path))
    assert code == 0, err
    assert "Telemetry: " in out
    assert err.strip() == (
        f"chassis-sdk replay: {path} ends in the middle of a line: read up to there"
    )


@pytest.mark.integration
@pytest.mark.parametrize("suffix", ["jsonl", "mcap"])
async def test_replay_prints_the_hosts_commands_when_the_capture_holds_them(
    tmp_path: Path, suffix: str
) -> None:
    path = tmp_path / f"run.{suffix}"
    async with ChassisSimulator() as sim, Chassis(sim.port, record=path) as robot:
        async with robot.telemetry() as telemetry:
            async for t in telemetry:
                await robot.set_velocity(0.2, 0.0)
                if t.linear >= 0.15:
                    break
        await robot.stop()
    code, out, err = await cli("replay", str(path))
    assert code == 0, err
    lines = out.splitlines()
    sent = [line for line in lines if "DriveVelocity" in line]
    assert sent, out[:2000]
    assert all(" > DriveVelocity: " in line for line in sent), sent
    assert any("linear_mm=200" in line for line in sent), sent
    assert any(" Telemetry: " in line and " > " not in line for line in lines)
    times = [float(line.split()[0]) for line in lines]
    assert times == sorted(times)  # one session, in order
    code, out, err = await cli("replay", str(path), "--json")
    assert code == 0, err
    objects = [json.loads(line) for line in out.splitlines()]
    commands = [o for o in objects if o.get("sent")]
    assert commands
    assert all(o["type"] == "DriveVelocity" for o in commands)
    assert not any(o.get("sent") for o in objects if o["type"] == "Telemetry")


@pytest.mark.integration
async def test_record_stopped_by_ctrl_c_says_what_it_recorded(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    async with ChassisSimulator() as sim:
        proc = await asyncio.create_subprocess_exec(
            *CLI, "record", sim.port, str(path), stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, cwd=ROOT,
        )  # fmt: skip
        assert proc.stdout is not None
        try:
            async with asyncio.timeout(20):
                while True:  # progress lines, once a second: until bytes were recorded
                    line = await proc.stdout.readline()
                    assert b"Ctrl-C to stop" in line, line
                    if re.search(rb": [1-9][\d,]* bytes", line):
                        break
            proc.send_signal(signal.SIGINT)
            async with asyncio.timeout(20):
                out, err = await proc.communicate()
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
    assert proc.returncode == 130, err
    assert f"to {path}" in out.decode().splitlines()[-1], out
    received, _ = telemetry_and_commands(path)
    assert received
