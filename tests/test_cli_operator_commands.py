"""The commands an operator reaches for: ``estop``, ``clear-faults`` and ``dock``, each
confirmed by telemetry (exit 3 when the chassis does not confirm), and ``info`` as a
health check (exit 4 on a fault, REMOTE_OFFLINE only information; exit 5 when it could
read only part, every field it read printed). The real
``chassis-sdk`` in a subprocess against the simulators on ptys; the failure paths run
on every transport (``CHASSIS_SDK_BACKEND`` reaches the subprocess).
"""

from __future__ import annotations

import json
import time

import pytest

from chassis_sdk.cli.info_command import EXIT_FAULT, verdict
from chassis_sdk.cli.operator import EXIT_UNCONFIRMED
from chassis_sdk.core.diagnosis import Diagnosis
from chassis_sdk.core.stats import LinkStats
from chassis_sdk.core.supervisor import ConnectionState
from chassis_sdk.devices.chassis.firmware import ChassisFirmware
from chassis_sdk.devices.chassis.health import (
    DRIVER_ERROR_MEANINGS,
    FAULT_STATUS,
    STATUS_MEANINGS,
    driver_findings,
    explain_drivers,
    explain_status,
)
from chassis_sdk.protocol import ChassisStatus, CommandId, DockingState, DriverError
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import cli, one_line, silent_pty

S = ChassisStatus


# --- the meanings ---------------------------------------------------------------------------


def test_every_status_bit_has_a_meaning_and_remote_offline_is_no_fault() -> None:
    singles = [m for m in ChassisStatus if m.value.bit_count() == 1]
    assert set(STATUS_MEANINGS) == set(singles)
    assert all(STATUS_MEANINGS[m] for m in singles)
    flags = explain_status(S.SOFTWARE_ESTOP | S.REMOTE_OFFLINE | (1 << 15))
    assert [(f.name, f.fault) for f in flags] == [
        ("SOFTWARE_ESTOP", True),
        ("REMOTE_OFFLINE", False),
        ("BIT_15", False),
    ]
    assert "normal under host control" in str(flags[1])
    assert str(flags[1]).startswith("REMOTE_OFFLINE (info): the remote control is off")
    assert all(f.fault == bool(m & FAULT_STATUS) for m in singles for f in explain_status(m))
    assert explain_status(0) == ()
    with pytest.raises(TypeError, match="status must be"):
        explain_status("SOFTWARE_ESTOP")  # type: ignore[arg-type]


def test_the_driver_meanings_name_what_diagnose_names() -> None:
    fw = ChassisFirmware()
    fw.set_driver_fault(0, DriverError.OVER_CURRENT | DriverError.DRIVER_OVER_TEMPERATURE_2)
    fw.set_driver_fault(3, DriverError(1 << 15))
    drivers = fw.driver_status()
    flags = explain_drivers(drivers)
    assert [f.name for f in flags] == list(driver_findings(drivers).faults)
    assert all(f.fault and f.meaning for f in flags)
    assert set(DRIVER_ERROR_MEANINGS) == {m for m in DriverError if m.value.bit_count() == 1}
    assert explain_drivers(ChassisFirmware().driver_status()) == ()


def test_verdict_exits_4_naming_the_faults_on_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    def report(*faults: str) -> Diagnosis:
        return Diagnosis(
            "board", "/dev/ttyX", ConnectionState.CONNECTED, LinkStats(), faults, ("battery",)
        )

    verdict(report())  # healthy: nothing, no exit
    assert capsys.readouterr().err == ""
    with pytest.raises(SystemExit) as exited:
        verdict(report("IMU reads |a| = 2.00 g", "LED request unanswered"))
    assert exited.value.code == EXIT_FAULT == 4
    assert one_line(capsys.readouterr().err) == (
        "chassis-sdk: info: board on /dev/ttyX: 2 faults: IMU reads |a| = 2.00 g, "
        "LED request unanswered"
    )


# --- estop and info ---------------------------------------------------------------------------


@pytest.mark.integration
async def test_estop_shows_in_info_which_exits_4_until_released() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("info", sim.port)
        assert code == 0, err
        assert "flags        REMOTE_OFFLINE (info): the remote control is off" in out
        assert "normal under host control" in out
        assert ": connected, OK" in out

        code, out, err = await cli("estop", sim.port)
        assert (code, out, err) == (0, "e-stop engaged (SOFTWARE_ESTOP set)\n", "")
        assert sim.firmware.software_estop

        code, out, err = await cli("info", sim.port)
        assert code == 4, err
        assert "flags        SOFTWARE_ESTOP (fault): the host's software emergency stop" in out
        assert "             REMOTE_OFFLINE (info): " in out  # information, listed too
        assert "FAULT  status SOFTWARE_ESTOP" in out
        assert one_line(err).endswith(": 1 fault: status SOFTWARE_ESTOP")

        code, out, err = await cli("estop", sim.port, "--release", "--json")
        assert code == 0, err
        outcome = json.loads(out)
        assert outcome["confirmed"] is True
        assert outcome["action"] == "release"
        assert outcome["status"] == ["REMOTE_OFFLINE"]
        assert outcome["message"] == "e-stop released (SOFTWARE_ESTOP clear)"
        assert not sim.firmware.software_estop
        code, _, err = await cli("info", sim.port)
        assert code == 0, err


@pytest.mark.integration
async def test_a_release_says_what_else_still_stops_the_robot() -> None:
    async with ChassisSimulator() as sim:
        sim.firmware.set_hardware_estop(True)
        code, out, err = await cli("estop", sim.port, "--release")
        assert code == 0, err
        assert out.startswith("e-stop released (SOFTWARE_ESTOP clear); still set: HARDWARE_ESTOP")
        assert "emergency-stop button is pressed" in out


@pytest.mark.integration
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


@pytest.mark.integration
async def test_info_on_a_silent_port_still_fails_at_the_first_request() -> None:
    with silent_pty() as quiet:
        started = time.monotonic()
        code, _, err = await cli("info", quiet, "--timeout", "0.2")
        elapsed = time.monotonic() - started
    assert code == 2, err
    assert elapsed < 0.2 * 3 * 2 + 5  # one request's attempts, not four requests'


# --- clear-faults -----------------------------------------------------------------------------


@pytest.mark.integration
async def test_clear_faults_clears_all_three_without_a_flag() -> None:
    async with ChassisSimulator() as sim:
        fw = sim.firmware
        fw.press_bumper(front=True)
        fw.press_bumper(front=False)
        fw.set_driver_fault(2, DriverError.HALL_SENSOR)
        code, out, err = await cli("clear-faults", sim.port)
        assert code == 0, err
        assert out == "faults cleared (driver faults, FRONT_BUMPER, REAR_BUMPER clear)\n"
        assert fw.status == S.REMOTE_OFFLINE


@pytest.mark.integration
async def test_info_explains_a_driver_fault_and_is_healthy_once_it_is_cleared() -> None:
    async with ChassisSimulator() as sim:
        sim.firmware.set_driver_fault(1, DriverError.HALL_SENSOR | DriverError(1 << 15))
        code, out, err = await cli("info", sim.port)
        assert code == 4, err
        assert "FRONT_RIGHT_DRIVER_ERROR (fault): the front-right motor driver reports" in out
        assert "front_right driver HALL_SENSOR (fault): the motor's hall sensor fails" in out
        assert "front_right driver BIT_15 (fault): an error bit the vendor document" in out
        assert "FAULT  front_right driver HALL_SENSOR" in out  # the diagnosis's own names
        assert "front_right driver HALL_SENSOR" in one_line(err)
        code, _, err = await cli("clear-faults", sim.port, "--driver")
        assert code == 0, err
        code, out, err = await cli("info", sim.port)
        assert code == 0, err
        assert "driver" not in out.split("chassis on")[0]  # no flag line left of it


@pytest.mark.integration
async def test_clear_faults_clears_only_what_is_flagged() -> None:
    async with ChassisSimulator() as sim:
        fw = sim.firmware
        fw.press_bumper(front=True)
        fw.press_bumper(front=False)
        code, out, err = await cli("clear-faults", sim.port, "--rear-bumper")
        assert code == 0, err
        assert out.startswith("faults cleared (REAR_BUMPER clear); still set: FRONT_BUMPER")
        assert fw.front_bumper
        assert not fw.rear_bumper


@pytest.mark.integration
async def test_clear_faults_with_a_bumper_held_exits_3_naming_what_remains() -> None:
    async with ChassisSimulator() as sim:
        fw = sim.firmware
        fw.hold_bumper(front=True)
        fw.set_driver_fault(0, DriverError.OVER_CURRENT)
        code, out, err = await cli("clear-faults", sim.port, "--timeout", "0.5")
        assert code == EXIT_UNCONFIRMED == 3, err
        assert out == ""
        line = one_line(err)
        assert "clear-faults: not confirmed: FRONT_BUMPER still set after 0.5 s" in line
        assert "the front bumper is triggered" in line
        assert not any(fw.driver_errors)  # what could be cleared was
        code, out, err = await cli("clear-faults", sim.port, "--timeout", "0.5", "--json")
        assert code == 3
        outcome = json.loads(out)
        assert outcome["confirmed"] is False
        assert outcome["remaining"] == ["FRONT_BUMPER"]
        fw.hold_bumper(front=True, held=False)  # let go: now it clears
        code, _, err = await cli("clear-faults", sim.port, "--front-bumper")
        assert code == 0, err
        assert not fw.front_bumper


# --- dock -------------------------------------------------------------------------------------


@pytest.mark.integration
async def test_dock_start_and_stop_are_confirmed() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli("dock", sim.port, "start")
        assert (code, out) == (0, "docking started (DOCKING_ENABLED set, docking SEARCHING)\n"), err
        assert sim.firmware.docking_enabled
        code, out, err = await cli("dock", sim.port, "stop", "--json")
        assert code == 0, err
        outcome = json.loads(out)
        assert (outcome["confirmed"], outcome["docking"]) == (True, "EXITED")
        assert sim.firmware.docking_state is DockingState.EXITED
        assert not sim.firmware.docking_enabled


# --- a chassis that does not confirm, and the everyday failures -------------------------------


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "ignored", "before", "says"),
    [
        pytest.param(("estop",), CommandId.EMERGENCY_STOP, None, "SOFTWARE_ESTOP not set", id="estop"),
        pytest.param(("estop", "--release"), CommandId.EMERGENCY_STOP, "estop", "SOFTWARE_ESTOP still set", id="release"),
        pytest.param(("dock", "start"), CommandId.DOCKING, None, "DOCKING_ENABLED not set", id="dock-start"),
        pytest.param(("dock", "stop"), CommandId.DOCKING, "dock", "DOCKING_ENABLED still set", id="dock-stop"),
        pytest.param(("clear-faults", "--driver"), CommandId.CLEAR_FAULTS, "driver", "FRONT_LEFT_DRIVER_ERROR still set", id="clear"),
    ],
)  # fmt: skip
async def test_a_chassis_that_does_not_confirm_exits_3_in_one_line(
    args: tuple[str, ...], ignored: CommandId, before: str | None, says: str
) -> None:
    async with ChassisSimulator() as sim:
        fw = sim.firmware
        if before == "estop":
            fw.software_estop = True
        elif before == "dock":
            fw.docking_enabled = True
        elif before == "driver":
            fw.set_driver_fault(0, DriverError.OVERLOAD)
        fw.ignored.add(ignored)
        code, out, err = await cli(args[0], sim.port, *args[1:], "--timeout", "0.3")
        assert code == 3, err
        assert out == ""
        assert f"{args[0]}: not confirmed: {says} after 0.3 s" in one_line(err)
        assert "Traceback" not in err
        assert any(getattr(c, "id", None) == ignored for _, c in fw.received)  # it was sent


@pytest.mark.integration
async def test_the_wrong_device_is_one_line_and_nothing_is_written() -> None:
    async with BoardSimulator() as board:
        for args in (("estop",), ("clear-faults",), ("dock", "start")):
            code, out, err = await cli(args[0], board.port, *args[1:], "--timeout", "0.5")
            assert code == 1
            assert out == ""
            line = one_line(err)
            assert "none is a chassis frame: is it a board?" in line
            # Not "Try --device board": that would only say a board cannot (issue 44, 9).
            assert "--device" not in line, line
            assert line.endswith(
                f"{args[0]} works on a chassis only (`chassis-sdk detect` says which device it is)"
            )
        assert len(board.firmware.received) == 0
        code, out, err = await cli("dock", board.port, "start", "--device", "board")
        assert code == 1
        assert one_line(err) == "chassis-sdk: dock: a board cannot dock (devices that can: chassis)"
        assert len(board.firmware.received) == 0


@pytest.mark.integration
async def test_no_port_is_a_usage_error_and_a_silent_port_is_no_answer() -> None:
    for args in (("estop",), ("clear-faults", "--driver"), ("dock", "stop")):
        code, _, err = await cli(*args, env={"CHASSIS_SDK_PORT": ""})
        assert code == 2
        assert (
            f"chassis-sdk {args[0]}: error: no port given (give PORT, or set CHASSIS_SDK_PORT)"
            in err
        )
    code, _, err = await cli("estop", "/dev/ttyX", "--timeout", "0")
    assert code == 2
    assert "argument --timeout" in err
    with silent_pty() as quiet:
        code, _, err = await cli("estop", quiet, "--timeout", "0.3")
    assert code == 2  # nothing answered: not "did not confirm"
    assert "no 0x81 chassis telemetry from" in one_line(err)
