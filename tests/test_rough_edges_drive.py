"""Issue 28's rough edges around driving, waiting and arguments (rows 1, 2, 11, 17, 18,
22): the real ``chassis-sdk`` and user scripts in a subprocess against the simulators
or a silent pty, each failure one line on stderr with no traceback and the exit code
docs/cli.md gives it, and the API refusing a wrong type with ``TypeError``.
"""

from __future__ import annotations

import asyncio
import signal
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import pytest

from chassis_sdk import Board, Chassis, ChassisError, ConnectionState
from chassis_sdk.devices.chassis.firmware import ChassisFirmware
from chassis_sdk.protocol import ChassisStatus, DriverError, DriveVelocity
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import ROOT, cli, one_line, running, silent_pty
from .support.helpers import drives

# --- user scripts under chassis_sdk.run --------------------------------------------------------


async def _script(tmp_path: Path, body: str, *args: str) -> tuple[asyncio.subprocess.Process, Path]:
    path = tmp_path / "operator_script.py"
    path.write_text(textwrap.dedent(body))
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(path), *args, cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    return proc, path


def _script_line(err: str) -> str:
    """The whole of stderr is one line named after the script, with no traceback."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("operator_script.py: "), err
    return lines[0]


async def test_row2_wait_for_times_out_with_an_sdk_error_on_one_line(tmp_path: Path) -> None:
    async with ChassisSimulator() as sim:
        proc, _ = await _script(
            tmp_path,
            """
            import sys
            import chassis_sdk

            async def main() -> None:
                async with chassis_sdk.Chassis(sys.argv[1]) as robot:
                    await robot.wait_for(lambda t: False, timeout=0.3)

            chassis_sdk.run(main(), one_line_errors=True)
            """,
            sim.port,
        )
        async with asyncio.timeout(20):
            _, err = await proc.communicate()
    assert proc.returncode == 2, err  # the timeout's status, as for a request's
    assert "no telemetry satisfied the condition in 0.3 s" in _script_line(err.decode())


async def test_row2_every_public_waiter_raises_an_sdk_error_that_is_a_timeout() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        with pytest.raises(ChassisError) as waited:
            await robot.wait_for(lambda t: False, timeout=0.2)
        assert isinstance(waited.value, TimeoutError)
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        Chassis(sim.port, reconnect=True) as robot,
    ):
        states = robot.connection_states()
        sim.unplug()  # and not plugged back: the device reconnects for ever
        async for state in states:
            if state is ConnectionState.RECONNECTING:
                break
        with pytest.raises(ChassisError, match="not connected within 0.05 s") as connected:
            await robot.wait_connected(0.05)
        assert isinstance(connected.value, TimeoutError)


async def test_row22_ctrl_c_in_a_script_is_quiet_exit_130_and_the_robot_stopped(
    tmp_path: Path,
) -> None:
    async with ChassisSimulator() as sim:
        proc, _ = await _script(
            tmp_path,
            """
            import asyncio
            import sys
            import chassis_sdk

            async def main() -> None:
                async with chassis_sdk.Chassis(sys.argv[1]) as robot:
                    await robot.set_velocity(0.3, 0.0)
                    print("driving", flush=True)
                    while True:
                        await robot.set_velocity(0.3, 0.0)
                        await asyncio.sleep(0.05)

            chassis_sdk.run(main(), one_line_errors=True)
            """,
            sim.port,
        )
        assert proc.stdout is not None
        async with asyncio.timeout(20):
            assert await proc.stdout.readline() == b"driving\n"
            proc.send_signal(signal.SIGINT)
            _, err = await proc.communicate()
            while not drives(sim) or drives(sim)[-1] != DriveVelocity(0, 0.0):
                await asyncio.sleep(0.01)
    assert proc.returncode == 130
    assert err.decode() == ""  # quiet: no KeyboardInterrupt traceback
    assert any(d.linear_mm == 300 for d in drives(sim))


# --- row 18: TypeError for a wrong type, ValueError for a bad value; the servo range ----------


async def test_row18_a_wrong_type_is_a_type_error_and_nothing_is_written() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        for linear in ("0.1", None, True):
            with pytest.raises(TypeError, match="linear must be a number"):
                await robot.set_velocity(linear, 0)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="linear must be finite"):
            await robot.set_velocity(float("nan"), 0)
        await robot.get_firmware_version()  # everything written before it has arrived
        assert drives(sim) == []


async def test_row18_the_servo_range_is_enforced_before_a_byte_is_written() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board:
        assert board.servo_range == (0.0, 180.0)
        for angle in (400.0, -0.1, 180.1):
            with pytest.raises(ValueError, match="out of range: the servo takes 0 to 180"):
                await board.set_servo(1, angle)
        with pytest.raises(TypeError, match="angle must be a number"):
            await board.set_servo(1, "90")  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="not an integer"):
            await board.set_servo(1.0, 90)  # type: ignore[arg-type]
        assert sim.firmware.servo == {1: 0.0, 2: 0.0}
        await board.set_servo(1, 180)
        await board.set_servo(2, 0.0)
        await board.get_led()  # the servo frames have arrived by its reply
        assert sim.firmware.servo == {1: 180.0, 2: 0.0}


def test_row18_argument_types_refuse_a_type_error_too(
    capsys: pytest.CaptureFixture[str],
) -> None:
    import argparse

    from chassis_sdk.cli.arguments import arg_type

    def must_be_int(value: object) -> object:
        if not isinstance(value, int):
            raise TypeError(f"n must be an integer, got {value!r}")
        return value

    parser = argparse.ArgumentParser(prog="x")
    parser.add_argument("--n", type=arg_type(float, must_be_int))
    with pytest.raises(SystemExit) as exited:
        parser.parse_args(["--n", "1.5"])
    assert exited.value.code == 2
    assert "argument --n: n must be an integer, got 1.5" in capsys.readouterr().err


# --- row 1: a chassis whose motion is blocked is refused at once --------------------------------


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


async def test_row1_motion_blocked_is_the_device_s_own_public_answer() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.wait_for(lambda t: True, timeout=2.0)
        assert robot.motion_blocked() == ()
        await robot.emergency_stop()
        sim.firmware.hold_bumper(front=False)
        await robot.wait_for(lambda t: bool(t.status & ChassisStatus.REAR_BUMPER), timeout=2.0)
        assert robot.motion_blocked() == ("SOFTWARE_ESTOP", "REAR_BUMPER")
    async with BoardSimulator() as board_sim, Board(board_sim.port) as board:
        assert board.motion_blocked() == ()  # a board reports nothing that blocks it


# --- row 17: a velocity required, a sane duration, conservative caps, Ctrl-C ------------------


@pytest.mark.parametrize(
    ("args", "says"),
    [
        pytest.param((), "drive: give a velocity: --linear V and/or --angular W", id="no-velocity"),
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


async def test_row17_a_profile_cannot_raise_the_caps_past_the_ceiling(tmp_path: Path) -> None:
    config = tmp_path / "chassis-sdk.toml"
    config.write_text("[limits]\nmax_linear = 10\n")
    code, _, err = await cli("--config", str(config), "drive", "/dev/ttyX", "--linear", "1")
    assert code == 2, err
    assert "max_linear must be a finite number 0 to 2 m/s" in one_line(err)


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


async def test_row17_ctrl_c_during_drive_says_interrupted_and_zero_is_the_last_frame() -> None:
    async with (
        ChassisSimulator() as sim,
        running("drive", sim.port, "--linear", "0.3", "--duration", "20") as drive,
    ):
        await drive.wait_for_line(lambda line: line.startswith("driving"))
        drive.proc.send_signal(signal.SIGINT)
        code, out, err = await drive.finish()
        assert code == 130, err
        assert out.splitlines()[-1] == "interrupted; stopped"
        assert "Traceback" not in err
        assert err == ""
        async with asyncio.timeout(5):
            while not drives(sim) or drives(sim)[-1] != DriveVelocity(0, 0.0):
                await asyncio.sleep(0.01)
        assert any(d.linear_mm == 300 for d in drives(sim))


# --- row 11: validated while parsing (exit 2), one exit code per situation ------------------


@pytest.mark.parametrize(
    ("args", "says"),
    [
        pytest.param(("serve", "/dev/ttyX", "--foxglove-port", "70000"), "argument --foxglove-port: port=70000 is out of range", id="serve-port"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--broker", "http://x"), "argument --broker: must be mqtt://HOST:PORT or mqtts://HOST:PORT, got 'http://x'", id="broker-http"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--broker", "mqtt://h:99999"), "argument --broker: has a bad port", id="broker-port"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "a/b#"), "argument --robot-id: robot_id must be letters, digits, '-' or '_', got 'a/b#'", id="robot-id"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--prefix", "+"), "argument --prefix: prefix must be letters", id="prefix"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--rate", "1000"), "argument --rate: rate must be a finite number 0 to 100", id="bridge-rate"),
        pytest.param(("sim", "chassis", "--noise", "2"), "argument --noise: noise must be a finite number 0 to 1, got 2.0", id="sim-noise"),
        pytest.param(("sim", "chassis", "--drop", "-0.1"), "argument --drop: drop must be a finite number 0 to 1", id="sim-drop"),
    ],
)  # fmt: skip
async def test_row11_bad_arguments_are_refused_while_parsing(
    args: tuple[str, ...], says: str
) -> None:
    code, out, err = await cli(*args)
    assert code == 2, err
    assert says in err
    assert "Traceback" not in err
    assert out == ""  # nothing printed first ("bridging ... as robots/a/b#")


async def test_row11_a_bad_broker_from_the_environment_is_refused_while_parsing() -> None:
    code, out, err = await cli(
        "bridge", "/dev/ttyX", "--robot-id", "r1", env={"CHASSIS_SDK_BROKER": "http://y"}
    )
    assert code == 2, err
    assert "argument --broker: must be mqtt://HOST:PORT or mqtts://HOST:PORT, got 'http://y'" in err
    assert out == ""


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
