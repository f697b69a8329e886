"""Finding and opening the port from the command line: ``ports`` with each port's
access, ``detect`` listening on every port (and on a silent one), the port, baud rate
and device from the environment; the real ``chassis-sdk`` in a subprocess against the
simulators, a silent pty and ports that are not there.

Every everyday failure is one line on stderr, with no traceback and no log line before
it, and an exit code that says it failed. Each command's own tests are in
test_cli_<command>.py (drive, monitor, captures, operator_commands).
"""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import tty

import pytest
from serial.tools.list_ports_common import ListPortInfo

from chassis_sdk.cli import main as cli_main
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import CLI, ROOT, cli, one_line, silent_pty

pytestmark = pytest.mark.integration

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
