"""The example scripts and the command line, run as a user would, in subprocesses."""

from __future__ import annotations

import asyncio
import os
import sys
import tty
from pathlib import Path

import pytest

from chassis_sdk.sim import ChassisSimulator

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


async def run(*args: str, timeout: float = 60.0) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        cwd=ROOT,
    )
    async with asyncio.timeout(timeout):
        out, err = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


@pytest.mark.timeout(120)
async def test_every_example_runs_against_the_simulator() -> None:
    assert len(EXAMPLES) >= 6
    results = await asyncio.gather(*(run(str(path)) for path in EXAMPLES))
    for path, (code, out, err) in zip(EXAMPLES, results, strict=True):
        assert code == 0, f"{path.name} failed:\n{out}\n{err}"
        assert out.strip(), path.name


async def test_example_takes_a_port_argument() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await run(
            str(ROOT / "examples" / "chassis_info_and_telemetry.py"), sim.port
        )
    assert code == 0, err
    assert "ZKWL-brush-motor-chassis" in out


@pytest.mark.parametrize("flag", [[], ["--board"]], ids=["chassis", "board"])
async def test_demo_exits_zero_and_shows_what_it_does(flag: list[str]) -> None:
    code, out, err = await run("-m", "chassis_sdk.cli", "demo", *flag)
    assert code == 0, err
    assert "done:" in out
    assert "v=" in out


async def test_info_against_a_running_simulator() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await run("-m", "chassis_sdk.cli", "info", sim.port)
    assert code == 0, err
    assert "firmware     103" in out
    assert "2024-01-02" in out


async def test_missing_port_is_one_clear_line() -> None:
    code, _out, err = await run("-m", "chassis_sdk.cli", "info", "/dev/ttyDOESNOTEXIST")
    assert code == 1
    assert err.strip().count("\n") == 0
    assert "no such device" in err
    assert "Traceback" not in err


async def test_silent_port_says_what_was_expected() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        code, _out, err = await run(
            "-m", "chassis_sdk.cli", "info", os.ttyname(slave), "--timeout", "0.2"
        )
    finally:
        os.close(master)
        os.close(slave)
    assert code == 2
    assert "no reply to FIRMWARE_VERSION" in err
    assert "Traceback" not in err


async def test_bad_argument_is_refused_before_connecting() -> None:
    async with ChassisSimulator() as sim:
        code, _out, err = await run(
            "-m", "chassis_sdk.cli", "drive", sim.port, "--linear", "nan", "--duration", "0.1"
        )
    assert code == 1
    assert "linear must be finite" in err
