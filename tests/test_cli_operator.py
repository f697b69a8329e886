"""The operator's first hour: the real ``chassis-sdk`` in a subprocess against the
simulators on ptys and TCP, a silent pty and the other device's simulator; the cable
pulled during ``monitor``, ``drive`` and ``record``; SIGTERM during ``drive``.

Every everyday failure is one line on stderr, with no traceback and no log line before
it, and an exit code that says it failed.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import json
import os
import re
import signal
import subprocess
import tty
from pathlib import Path

import pytest
from serial.tools.list_ports_common import ListPortInfo

from chassis_sdk.cli import main as cli_main
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import CLI, ROOT, cli, one_line, running, silent_pty
from .support.helpers import drives

# --- finding the port ---------------------------------------------------------------------


def test_ports_lists_every_port_with_its_access(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    with silent_pty() as free, silent_pty() as held:
        usb = ListPortInfo(free)
        usb.vid, usb.pid, usb.serial_number = 0x1A86, 0x7523, "A1B2"
        usb.manufacturer, usb.description = "QinHeng Electronics", "USB Serial"
        fake = [ListPortInfo("/dev/ttyGONE"), usb, ListPortInfo(held)]
        monkeypatch.setattr("serial.tools.list_ports.comports", lambda: fake)
        with open(held) as holder:
            fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as pyserial's exclusive open
            assert cli_main(["ports", "--json"]) == 0
            rows = json.loads(capsys.readouterr().out)
            assert cli_main(["ports"]) == 0
            text = capsys.readouterr().out
    by_device = {row["device"]: row for row in rows}
    assert rows[0]["device"] == free  # USB first
    assert by_device[free]["vid_pid"] == "1A86:7523"
    assert by_device[free]["serial_number"] == "A1B2"
    assert by_device[free]["access"] == "ok"
    assert by_device[held]["access"].startswith("busy: held by this process")
    assert by_device["/dev/ttyGONE"]["access"] == "missing"
    assert "USB 1A86:7523  QinHeng Electronics, USB Serial  serial A1B2  [ok]" in text


def _sim_process(kind: str) -> tuple[subprocess.Popen[bytes], str]:
    proc = subprocess.Popen([*CLI, "sim", kind], stdout=subprocess.PIPE, cwd=ROOT)
    assert proc.stdout is not None
    return proc, proc.stdout.readline().decode().strip()


def test_detect_without_a_port_listens_on_every_port(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    chassis, chassis_port = _sim_process("chassis")
    board, board_port = _sim_process("board")
    try:
        master, slave = os.openpty()
        tty.setraw(slave)
        quiet = os.ttyname(slave)
        try:
            fake = [ListPortInfo(p) for p in (chassis_port, board_port, quiet)]
            monkeypatch.setattr("serial.tools.list_ports.comports", lambda: fake)
            assert cli_main(["detect", "--seconds", "1.5"]) == 0
            out = capsys.readouterr().out
            assert f"{chassis_port}: chassis\n" in out
            assert f"{board_port}: board\n" in out
            assert f"{quiet}: nothing recognisable within 1.5 s" in out
            os.set_blocking(master, False)
            with pytest.raises(BlockingIOError):  # listening only: nothing was written
                os.read(master, 64)
        finally:
            os.close(master)
            os.close(slave)
    finally:
        for proc in (chassis, board):
            proc.terminate()
            proc.wait()


async def test_row11_detect_on_a_silent_port_exits_2_like_info_and_monitor() -> None:
    with silent_pty() as quiet:
        code, out, err = await cli("detect", quiet, "--seconds", "0.5")
        assert code == 2, err
        assert out == ""
        line = one_line(err)
        assert line.startswith(f"chassis-sdk: {quiet}: nothing recognisable within 0.5 s")
        code, _, err = await cli("info", quiet, "--timeout", "0.3")
        assert code == 2, err  # the same code for the same silent port
    code, _, err = await cli("detect", "/dev/ttyDOESNOTEXIST")
    assert code == 1  # a port that does not open is an everyday failure, as for info
    assert "no such device" in one_line(err)
    async with ChassisSimulator() as sim:
        code, out, err = await cli("detect", sim.port)
    assert (code, out) == (0, "chassis\n"), err


async def test_baudrate_and_environment_defaults_reach_every_command() -> None:
    async with ChassisSimulator() as sim, BoardSimulator() as board:
        code, out, err = await cli("info", "-b", "57600", env={"CHASSIS_SDK_PORT": sim.port})
        assert code == 0, err
        assert "hardware     ZKWL-brush-motor-chassis" in out
        code, out, err = await cli(
            "info", env={"CHASSIS_SDK_PORT": board.port, "CHASSIS_SDK_PROTOCOL": "board"}
        )
        assert code == 0, err
        assert "led" in out
    code, _, err = await cli("info", env={"CHASSIS_SDK_PORT": ""})
    assert code == 2
    assert "no port given (give PORT, or set CHASSIS_SDK_PORT)" in err
    code, _, err = await cli("info", "/dev/ttyX", "--baudrate", "0")
    assert code == 2
    assert "baudrate" in err
    code, _, err = await cli("info", "/dev/ttyX", env={"CHASSIS_SDK_PROTOCOL": "tractor"})
    assert code == 2
    assert "CHASSIS_SDK_PROTOCOL='tractor' is not a known device (known: chassis, board)" in err


# --- one line, never a traceback ----------------------------------------------------------


@pytest.mark.parametrize(
    ("port", "says"),
    [
        pytest.param("socket://localhost", "needs a host and a port: socket://HOST:PORT", id="no-tcp-port"),
        pytest.param("/dev/null", "not a serial port", id="dev-null"),
        pytest.param("/tmp", "it is a directory, not a serial port", id="directory"),
        pytest.param("socket://no-such-host.invalid:5000", "cannot resolve the host 'no-such-host.invalid'", id="unknown-host"),
        pytest.param("/dev/ttyDOESNOTEXIST", "no such device", id="missing"),
    ],
)  # fmt: skip
async def test_everyday_failures_are_one_line(port: str, says: str) -> None:
    code, _, err = await cli("info", port, "--timeout", "0.3")
    assert code == 1
    assert says in one_line(err)


async def test_info_on_a_silent_port_is_one_line_without_a_log_before_it() -> None:
    with silent_pty() as quiet:
        code, _, err = await cli("info", quiet, "--timeout", "0.3")
    assert code == 2
    assert "no reply" in one_line(err)


# --- monitor ----------------------------------------------------------------------------------


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


# --- drive ------------------------------------------------------------------------------------


async def test_drive_refuses_bad_numbers_before_opening_the_port() -> None:
    for bad in ("nan", "inf", "x"):
        code, out, err = await cli("drive", "/dev/ttyDOESNOTEXIST", "--linear", bad)
        assert code == 2
        assert "argument --linear" in err
        assert "could not open" not in err
        assert "driving" not in out


async def test_drive_does_not_claim_success_on_a_silent_port_or_another_device() -> None:
    with silent_pty() as quiet:
        code, out, err = await cli("drive", quiet, "--linear", "0.2", "--timeout", "0.5")
    assert code == 2
    assert "driving" not in out
    assert "no 0x81 chassis telemetry" in one_line(err)
    async with BoardSimulator() as board:
        code, out, err = await cli("drive", board.port, "--linear", "0.2", "--timeout", "0.5")
        assert code == 1
        assert "driving" not in out
        assert "none is a chassis frame" in one_line(err)
        assert board.firmware.received == type(board.firmware.received)()  # nothing written


async def test_drive_clamps_to_the_default_limits_and_says_so() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli(
            "drive", sim.port, "--linear", "2", "--angular", "-5", "--duration", "0.3"
        )
        assert code == 0, err
        assert "linear 2 m/s clamped to 0.5 m/s (--max-linear)" in out
        assert "angular -5 rad/s clamped to -1 rad/s (--max-angular)" in out
        assert max(d.linear_mm for d in drives(sim)) == 500
        assert min(d.angular for d in drives(sim)) == pytest.approx(-1.0)
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)


async def test_drive_ends_at_once_when_the_link_is_lost() -> None:
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        running("drive", sim.port, "--linear", "0.2", "--duration", "20") as drive,
    ):
        await drive.wait_for_line(lambda line: line.startswith("driving"))
        sim.unplug()
        code, out, err = await drive.finish(timeout=5)
    assert code == 1
    assert "lost the link to" in one_line(err)
    assert "stopped" not in out


async def test_sigterm_during_drive_leaves_zero_as_the_last_frame() -> None:
    async with (
        ChassisSimulator() as sim,
        running("drive", sim.port, "--linear", "0.3", "--duration", "20") as drive,
    ):
        await drive.wait_for_line(lambda line: line.startswith("driving"))
        drive.proc.send_signal(signal.SIGTERM)
        code, _, _ = await drive.finish()
        assert code == 128 + signal.SIGTERM
        async with asyncio.timeout(5):
            while not drives(sim) or drives(sim)[-1] != DriveVelocity(0, 0.0):
                await asyncio.sleep(0.01)
        assert any(d.linear_mm == 300 for d in drives(sim))


# --- record, replay, sim ----------------------------------------------------------------------


async def test_record_reports_an_unplug_and_a_replug_and_writes_them_down(tmp_path: Path) -> None:
    path = tmp_path / "cap.jsonl"
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        running("record", sim.port, str(path), "--seconds", "3") as rec,
    ):
        await rec.wait_for_line(lambda line: re.search(r": [1-9][\d,]* bytes", line) is not None)
        sim.unplug()
        await rec.wait_for_line(lambda line: "LINK LOST" in line)
        await sim.replug()
        code, out, err = await rec.finish()
    assert code == 0, err
    assert "\r" not in out  # piped: plain lines, never a carriage return
    assert "the link dropped 1 time(s)" in out
    events = [json.loads(line).get("event") for line in path.read_text().splitlines()]
    assert [e for e in events if e] == ["disconnected", "reconnected"]
    code, out, err = await cli("replay", str(path))
    assert code == 0, err
    assert "Telemetry: " in out


async def test_record_fails_when_the_link_is_not_restored(tmp_path: Path) -> None:
    path = tmp_path / "cap.jsonl"
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        running("record", sim.port, str(path), "--seconds", "2") as rec,
    ):
        await rec.wait_for_line(lambda line: re.search(r": [1-9][\d,]* bytes", line) is not None)
        sim.unplug()
        code, _, err = await rec.finish()
    assert code == 1
    assert "was lost and not restored" in one_line(err)


async def test_replay_with_the_wrong_protocol_says_so(tmp_path: Path) -> None:
    path = tmp_path / "board.jsonl"
    async with BoardSimulator() as board:
        code, _, err = await cli("record", board.port, str(path), "--seconds", "0.5")
    assert code == 0, err
    code, out, err = await cli("replay", str(path), "--protocol", "chassis")
    assert code == 1
    assert out == ""
    assert "no chassis frames in" in one_line(err)
    assert "it looks like a board capture; try --device board" in err


async def test_sim_removes_its_port_link_on_sigterm() -> None:
    async with running("sim", "chassis") as sim:
        port = (await sim.wait_for_line(lambda line: True)).strip()
        assert os.path.islink(port)
        sim.proc.send_signal(signal.SIGTERM)
        code, _, _ = await sim.finish()
    assert code == 128 + signal.SIGTERM
    assert not os.path.lexists(port)


@pytest.mark.parametrize("suffix", [".jsonl", ".mcap"])
async def test_replay_as_a_device_feeds_an_unmodified_chassis(tmp_path: Path, suffix: str) -> None:
    from chassis_sdk import Chassis, ConnectionLostError, Telemetry
    from chassis_sdk.recording import capture

    path = tmp_path / f"cap{suffix}"
    async with ChassisSimulator() as sim:
        await capture.record(sim.port, path, seconds=1.0)
    recorded = [
        m.seq for _, m in capture.decode_capture(path, "chassis") if isinstance(m, Telemetry)
    ]
    assert len(recorded) >= 40
    async with running("replay", str(path), "--as-device", "--tcp", "0") as replay:
        port = (await replay.wait_for_line(lambda line: True)).strip()
        seen: list[int] = []
        async with Chassis(port) as robot:
            await robot.set_velocity(0.2, 0.0)  # written, counted, never acted on
            with contextlib.suppress(ConnectionLostError):
                async for t in robot.telemetry():
                    seen.append(t.seq)
        code, out, err = await replay.finish()
    assert code == 0, err
    # What the robot sent, with its own sequence numbers, in order.
    assert len(seen) >= len(recorded) - 5
    assert seen == recorded[len(recorded) - len(seen) :]
    assert "the application wrote" in out
    assert "DriveVelocity" in out


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
