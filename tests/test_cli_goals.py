"""``chassis-sdk move``, ``turn`` and ``goto``: the real command line in a subprocess
against the simulated chassis on a pty: each goal ends within tolerance with its line;
Ctrl-C stops it at once with a zero as the last frame; a blocked chassis is refused
before anything is written (exit 4); a timeout exits 1 saying how far it got."""

from __future__ import annotations

import math
import signal

import pytest

from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.cli import cli, one_line, running
from .support.helpers import drives

pytestmark = pytest.mark.integration


@pytest.mark.parametrize(
    ("args", "done", "truth"),
    [
        (("move", "0.3"), "move 0.3 m: done in", lambda x, y, h: abs(x - 0.3) < 0.015),
        (("turn", "-90"), "turn -90°: done in", lambda x, y, h: abs(h + math.pi / 2) < 0.03),
        (("goto", "0.2", "0.2"), "goto (0.2, 0.2): done in", lambda x, y, h: abs(y - 0.2) < 0.02),
    ],
    ids=["move", "turn", "goto"],
)
async def test_a_goal_from_the_command_line_ends_within_tolerance(
    args: tuple[str, ...], done: str, truth: object
) -> None:
    async with ChassisSimulator() as sim:
        name, *rest = args
        code, out, err = await cli(name, sim.port, *rest)
        assert code == 0, err
        assert out.splitlines()[-1].startswith(done), out
        assert truth(*sim.firmware.pose)  # type: ignore[operator]
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)


async def test_ctrl_c_stops_a_goal_with_a_zero_last() -> None:
    async with ChassisSimulator() as sim, running("move", sim.port, "5") as move:
        await move.wait_for_line(lambda line: "m/s" in line and "+0.00 m/s" not in line)
        move.proc.send_signal(signal.SIGINT)
        code, out, err = await move.finish()
        assert code == 130, err
        assert out.splitlines()[-1] == "interrupted; stopped"
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)
        assert any(d.linear_mm > 0 for d in drives(sim))


async def test_a_blocked_chassis_is_refused_before_anything_is_written() -> None:
    async with ChassisSimulator() as sim:
        sim.firmware.software_estop = True
        code, _, err = await cli("goto", sim.port, "1", "0")
        assert code == 4, err
        assert "e-stopped (software)" in one_line(err)
        assert all(d == DriveVelocity(0, 0.0) for d in drives(sim))


async def test_a_timeout_stops_and_says_how_far_it_got() -> None:
    async with ChassisSimulator() as sim:
        code, _, err = await cli("move", sim.port, "3", "--timeout", "0.5")
        assert code == 1, err
        assert "drive_distance did not finish in 0.5 s (" in one_line(err)
        assert "cm left)" in err
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("move", "PORT", "nan"), "metres"),
        (("turn", "PORT", "90", "--rate", "0"), "rate"),
        (("goto", "PORT", "1"), "argument x"),  # the port is optional: X Y are missing
    ],
)
async def test_bad_numbers_are_refused_while_parsing(args: tuple[str, ...], says: str) -> None:
    async with ChassisSimulator() as sim:
        code, _, err = await cli(*(sim.port if a == "PORT" else a for a in args))
        assert code == 2, err
        assert says in err
        assert drives(sim) == []
