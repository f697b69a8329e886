"""The ``drive`` command: the real ``chassis-sdk`` in a subprocess against the
simulators on ptys and TCP, a silent pty and the other device's simulator. A chassis
whose motion is blocked is refused before a velocity is written; a velocity is
required, bad numbers, the duration and the caps are refused while parsing, and the caps
are raised only explicitly; the link lost ends it at once; Ctrl-C and SIGTERM stop it
with zero as the last frame. Each failure is one line on stderr with no traceback and
the exit code docs/cli.md gives it. The rows named are those of issue 28, which asked
for them.
"""

from __future__ import annotations

import asyncio
import signal
from collections.abc import Callable
from pathlib import Path

import pytest

from chassis_sdk.devices.chassis.firmware import ChassisFirmware
from chassis_sdk.protocol import ChassisStatus, DriverError, DriveVelocity
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import cli, one_line, running, silent_pty
from .support.helpers import drives

# --- row 1: a chassis whose motion is blocked is refused at once --------------------------------


@pytest.mark.integration
@pytest.mark.parametrize(
    ("block", "says"),
    [
        pytest.param(
            lambda fw: setattr(fw, "software_estop", True),
            "the chassis is e-stopped (software); release it with "
            "`chassis-sdk estop {port} --release`",
            id="software-estop",
        ),
        pytest.param(
            lambda fw: fw.hold_bumper(front=True),
            "the chassis is stopped by its front bumper; free it, then "
            "`chassis-sdk clear-faults {port} --front-bumper`",
            id="held-bumper",
        ),
        pytest.param(
            lambda fw: fw.set_driver_fault(2, DriverError.OVER_CURRENT),
            "the chassis is stopped by a rear-left motor driver error; clear it with "
            "`chassis-sdk clear-faults {port} --driver`",
            id="driver-fault",
        ),
    ],
)
async def test_row1_drive_refuses_a_blocked_chassis_before_writing_a_velocity(
    block: Callable[[ChassisFirmware], None], says: str
) -> None:
    async with ChassisSimulator() as sim:
        block(sim.firmware)
        code, out, err = await cli("drive", sim.port, "--linear", "0.3", "--duration", "5")
        assert code == 4, err  # the device reports a fault, as info's exit says
        assert one_line(err) == "chassis-sdk: " + says.format(port=sim.port)
        assert "driving" not in out
        assert "stopped" not in out
        assert all(d == DriveVelocity(0, 0.0) for d in drives(sim))  # no velocity written


@pytest.mark.integration
async def test_row1_released_the_chassis_drives_again() -> None:
    async with ChassisSimulator() as sim:
        sim.firmware.software_estop = True
        assert sim.firmware.status & ChassisStatus.SOFTWARE_ESTOP
        code, _, err = await cli("drive", sim.port, "--linear", "0.2", "--duration", "0.3")
        assert code == 4, err
        code, _, err = await cli("estop", sim.port, "--release")
        assert code == 0, err
        code, out, err = await cli("drive", sim.port, "--linear", "0.2", "--duration", "0.3")
        assert code == 0, err
        assert "stopped" in out
        assert any(d.linear_mm == 200 for d in drives(sim))


# --- row 17: a velocity required, a sane duration, conservative caps, Ctrl-C or SIGTERM ------


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "says"),
    [
        pytest.param((), "chassis-sdk drive: error: give a velocity: --linear V and/or --angular W", id="no-velocity"),
        pytest.param(
            ("--linear", "0.1", "--duration", "1e9"),
            "argument --duration: duration must be a finite number 0 to 600 s",
            id="duration-1e9",
        ),
        pytest.param(
            ("--linear", "5", "--max-linear", "10"),
            "argument --max-linear: max_linear must be a finite number 0 to 2 m/s, got 10.0",
            id="max-linear-10",
        ),
        pytest.param(
            ("--angular", "1", "--max-angular", "9"),
            "argument --max-angular: max_angular must be a finite number 0 to 4 rad/s",
            id="max-angular-9",
        ),
        pytest.param(("--linear", "nan"), "argument --linear", id="linear-nan"),
        pytest.param(("--linear", "inf"), "argument --linear", id="linear-inf"),
        pytest.param(("--linear", "x"), "argument --linear", id="linear-not-a-number"),
    ],
)  # fmt: skip
async def test_row17_drive_arguments_are_refused_while_parsing(
    args: tuple[str, ...], says: str
) -> None:
    code, out, err = await cli("drive", "/dev/ttyDOESNOTEXIST", *args)
    assert code == 2, err
    assert says in err
    assert "Traceback" not in err
    assert "could not open" not in err  # refused before any port opens
    assert out == ""


@pytest.mark.integration
async def test_row17_a_profile_cannot_raise_the_caps_past_the_ceiling(tmp_path: Path) -> None:
    config = tmp_path / "chassis-sdk.toml"
    config.write_text("[limits]\nmax_linear = 10\n")
    code, _, err = await cli("--config", str(config), "drive", "/dev/ttyX", "--linear", "1")
    assert code == 2, err
    assert "max_linear must be a finite number 0 to 2 m/s" in one_line(err)


@pytest.mark.integration
async def test_row17_the_caps_are_raised_only_explicitly_and_the_clamp_says_so() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("drive", sim.port, "--linear", "5", "--duration", "0.2")
        assert code == 0, err
        assert (
            "linear 5 m/s clamped to 0.5 m/s (--max-linear); --max-linear raises it, up to 2 m/s"
            in out
        )
        assert max(d.linear_mm for d in drives(sim)) == 500
        sim.firmware.received.clear()
        code, out, err = await cli(
            "drive", sim.port, "--linear", "5", "--max-linear", "2", "--duration", "0.2"
        )
        assert code == 0, err
        assert "linear 5 m/s clamped to 2 m/s (--max-linear)\n" in out  # at the ceiling
        assert max(d.linear_mm for d in drives(sim)) == 2000
        sim.firmware.received.clear()
        code, out, err = await cli("drive", sim.port, "--angular", "0.5", "--duration", "0.2")
        assert code == 0, err
        assert "driving v=0 m/s, w=0.5 rad/s for 0.2 s" in out
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)
        assert any(d.angular == pytest.approx(0.5) for d in drives(sim))


@pytest.mark.integration
@pytest.mark.parametrize(
    ("sent", "exit_code"),
    [
        pytest.param(signal.SIGINT, 130, id="ctrl-c"),
        pytest.param(signal.SIGTERM, 128 + signal.SIGTERM, id="sigterm"),
    ],
)
async def test_ctrl_c_or_sigterm_during_drive_says_interrupted_and_zero_is_the_last_frame(
    sent: signal.Signals, exit_code: int
) -> None:
    async with (
        ChassisSimulator() as sim,
        running("drive", sim.port, "--linear", "0.3", "--duration", "20") as drive,
    ):
        await drive.wait_for_line(lambda line: line.startswith("driving"))
        drive.proc.send_signal(sent)
        code, out, err = await drive.finish()
        assert code == exit_code, err
        assert out.splitlines()[-1] == "interrupted; stopped"
        assert "Traceback" not in err
        assert err == ""
        async with asyncio.timeout(5):
            while not drives(sim) or drives(sim)[-1] != DriveVelocity(0, 0.0):
                await asyncio.sleep(0.01)
        assert any(d.linear_mm == 300 for d in drives(sim))


# --- a silent port or the other device, the default caps, the link lost ---------------------


@pytest.mark.integration
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


@pytest.mark.integration
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


@pytest.mark.integration
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
