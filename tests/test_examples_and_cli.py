"""The example scripts and the command line, run as a user would, in subprocesses; and
the docs that show them held to what they do: the testing page's snippet
(docs/testing.md) run as written, docs/cli.md's commands and synopsis against
``--help``."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import ROOT, cli, silent_pty

#: The examples that run against the built-in simulator (fleet_console needs a broker:
#: tests/test_bridge.py runs it against a real one).
EXAMPLES = sorted(p for p in (ROOT / "examples").glob("*.py") if p.name != "fleet_console.py")


@pytest.fixture(autouse=True)
def _own_temp_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What an example writes to a temporary directory (record_a_drive's recording) goes
    to the test's own, removed with it."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))


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


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.timeout(120)
async def test_every_example_runs_against_the_simulator() -> None:
    assert len(EXAMPLES) >= 6
    results = await asyncio.gather(*(run(str(path)) for path in EXAMPLES))
    for path, (code, out, err) in zip(EXAMPLES, results, strict=True):
        assert code == 0, f"{path.name} failed:\n{out}\n{err}"
        assert out.strip(), path.name


@pytest.mark.integration
@pytest.mark.timeout(120)
async def test_every_example_on_the_other_devices_port_fails_in_one_line() -> None:
    async def on_wrong_port(path: Path) -> tuple[int, str, str]:
        other = ChassisSimulator() if "board" in path.name else BoardSimulator()
        async with other:  # one each: ports are exclusive
            return await run(str(path), other.port)

    results = await asyncio.gather(*(on_wrong_port(path) for path in EXAMPLES))
    for path, (code, out, err) in zip(EXAMPLES, results, strict=True):
        lines = err.strip().splitlines()
        assert code == 1, f"{path.name}: {code}\n{out}\n{err}"
        assert len(lines) == 1, f"{path.name}: {err}"
        assert lines[0].startswith(f"{path.name}: "), err
        assert "is it another device, or the wrong baud rate?" in lines[0]


@pytest.mark.integration
@pytest.mark.slow
async def test_examples_print_names_not_numbers_and_end_stopped() -> None:
    results = await asyncio.gather(
        *(run(str(ROOT / "examples" / name)) for name in
          ("chassis_info_and_telemetry.py", "estop_and_faults.py", "drive_square.py"))
    )  # fmt: skip
    text = "".join(out for _, out, _ in results)
    assert "<ChassisStatus" not in text, text
    assert "<DriverError" not in text, text
    assert "REMOTE_OFFLINE" in text
    assert "faults latched: FRONT_BUMPER" in text
    assert "errors=none" in text
    assert "done: stopped (v=+0.00 m/s, w=+0.00 rad/s" in results[2][1]


@pytest.mark.integration
async def test_examples_say_what_they_do_in_words_that_mean_it() -> None:
    """Issue 44, item 12: the LED's state as the board reports it (not ``led off:
    True``), and the simulator's bumper pressed where it is pressed, said so."""
    (code, blink, err), (code2, faults, err2) = await asyncio.gather(
        run(str(ROOT / "examples" / "board_blink_and_beep.py")),
        run(str(ROOT / "examples" / "estop_and_faults.py")),
    )
    assert (code, code2) == (0, 0), err + err2
    assert "led off: True" not in blink
    assert blink.count("set_led(True): the led is on\n") == 3
    assert blink.count("set_led(False): the led is off\n") == 3
    assert "now: the led is off, the buzzer is off" in blink
    lines = faults.splitlines()
    pressed = lines.index(
        "simulator: pressing its front bumper (a fault for clear_faults() to clear)"
    )
    assert pressed < next(i for i, line in enumerate(lines) if line.startswith("faults latched"))


@pytest.mark.integration
async def test_an_example_piped_into_head_ends_quietly() -> None:
    """Issue 44, item 12: ``chassis_info_and_telemetry.py | head -3`` ends with exit
    status 0 and nothing on stderr, as ``chassis-sdk ... | head`` does."""
    read_end, write_end = os.pipe()
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(ROOT / "examples" / "chassis_info_and_telemetry.py"),
        stdout=write_end, stderr=asyncio.subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    os.close(write_end)
    with os.fdopen(read_end, "rb") as reader:  # head -3: three lines, then it goes
        head = [await asyncio.to_thread(reader.readline) for _ in range(3)]
    async with asyncio.timeout(30):
        _, err = await proc.communicate()
    assert head[0].startswith(b"firmware:")
    assert (proc.returncode, err.decode()) == (0, "")


@pytest.mark.integration
async def test_example_takes_a_port_argument() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await run(
            str(ROOT / "examples" / "chassis_info_and_telemetry.py"), sim.port
        )
    assert code == 0, err
    assert "ZKWL-brush-motor-chassis" in out


def snippet_of_the_testing_page() -> str:
    page = (ROOT / "docs" / "testing.md").read_text()
    match = re.search(r"```python\n(.*?)```", page, re.S)
    assert match, "no python block in docs/testing.md"
    return match.group(1)


@pytest.mark.integration
async def test_the_testing_page_snippet_survives_the_replug() -> None:
    snippet = snippet_of_the_testing_page()
    assert "await sim.replug()" in snippet
    # The block as written, then, inside its `async with`, 2.5 s of telemetry after the
    # replug (LOST comes 1.5 s after it without reconnect=True) and the state.
    check = """
    seen = 0
    async for _ in robot.telemetry():
        seen += 1
        if seen == 125:
            break
    result["state"] = robot.connection_state.value
    result["seen"] = seen
"""
    source = "async def snippet(result):\n" + textwrap.indent(snippet + check, "    ")
    scope: dict[str, Any] = {}
    exec(compile(source, "docs/testing.md", "exec"), scope)
    result: dict[str, Any] = {}
    async with asyncio.timeout(20):
        await scope["snippet"](result)
    assert result == {"state": "connected", "seen": 125}


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.parametrize("flag", [[], ["--board"]], ids=["chassis", "board"])
async def test_demo_exits_zero_and_shows_what_it_does(flag: list[str]) -> None:
    code, out, err = await run("-m", "chassis_sdk.cli", "demo", *flag)
    assert code == 0, err
    assert "done:" in out
    assert "v=" in out


@pytest.mark.integration
@pytest.mark.slow
async def test_the_demo_explains_the_status_where_it_first_shows_it() -> None:
    code, out, err = await cli("demo", timeout=60)
    assert code == 0, err
    lines = out.splitlines()
    first = next(i for i, line in enumerate(lines) if "status=REMOTE_OFFLINE" in line)
    assert "REMOTE_OFFLINE: the remote control is off" in lines[first + 1]
    assert "normal under host control" in lines[first + 1]
    assert "firmware     v1.0.3 (103)" in out


@pytest.mark.integration
async def test_info_against_a_running_simulator() -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await run("-m", "chassis_sdk.cli", "info", sim.port)
    assert code == 0, err
    assert "firmware     v1.0.3 (103)" in out
    assert "2024-01-02" in out


@pytest.mark.integration
async def test_missing_port_is_one_clear_line() -> None:
    code, _out, err = await run("-m", "chassis_sdk.cli", "info", "/dev/ttyDOESNOTEXIST")
    assert code == 1
    assert err.strip().count("\n") == 0
    assert "no such device" in err
    assert "Traceback" not in err


@pytest.mark.integration
async def test_silent_port_says_what_was_expected() -> None:
    with silent_pty() as quiet:
        code, _out, err = await run("-m", "chassis_sdk.cli", "info", quiet, "--timeout", "0.2")
    assert code == 2
    assert "no reply to FIRMWARE_VERSION" in err
    assert "Traceback" not in err


@pytest.mark.integration
async def test_bad_argument_is_refused_before_connecting() -> None:
    async with ChassisSimulator() as sim:
        code, _out, err = await run(
            "-m", "chassis_sdk.cli", "drive", sim.port, "--linear", "nan", "--duration", "0.1"
        )
    assert code == 2  # a usage error now: refused while parsing, before the port opens
    assert "argument --linear: linear must be finite" in err


@pytest.mark.integration
async def test_record_replay_and_detect(tmp_path: Path) -> None:
    cap = tmp_path / "cap.jsonl"
    async with ChassisSimulator() as sim:
        code, out, err = await run("-m", "chassis_sdk.cli", "detect", sim.port)
        assert (code, out.strip()) == (0, "chassis"), err
        code, out, err = await run(
            "-m", "chassis_sdk.cli", "record", sim.port, str(cap), "--seconds", "0.5"
        )
        assert code == 0, err
        assert "recorded" in out
    code, out, err = await run("-m", "chassis_sdk.cli", "replay", str(cap))
    assert code == 0, err
    assert out.count("Telemetry: ") >= 15  # 50 Hz for 0.5 s
    code, out, err = await run("-m", "chassis_sdk.cli", "replay", str(cap), "--json")
    first = json.loads(out.splitlines()[0])
    assert first["type"] == "Telemetry"
    assert first["docking"] == "SEARCHING"
    assert isinstance(first["wheels"]["front_left"], float)


@pytest.mark.integration
async def test_replay_of_a_file_that_is_not_a_capture(tmp_path: Path) -> None:
    bogus = tmp_path / "x.txt"
    bogus.write_text("hello\n")
    code, _out, err = await run("-m", "chassis_sdk.cli", "replay", str(bogus))
    assert code == 1
    assert "not a chassis-sdk capture" in err


@pytest.mark.integration
async def test_plot_writes_a_png(tmp_path: Path) -> None:
    cap, png = tmp_path / "cap.jsonl", tmp_path / "out.png"
    async with BoardSimulator() as sim:
        code, _, err = await run(
            "-m", "chassis_sdk.cli", "record", sim.port, str(cap), "--seconds", "0.5"
        )
        assert code == 0, err
    code, _out, err = await run("-m", "chassis_sdk.cli", "plot", str(cap), "-o", str(png))
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.integration
async def test_wrong_protocol_on_the_port_is_named() -> None:
    async with BoardSimulator() as sim:
        code, _out, err = await run("-m", "chassis_sdk.cli", "info", sim.port, "--timeout", "0.2")
    assert code == 1
    assert "none is a chassis frame: is it a board?" in err
    assert "Traceback" not in err


@pytest.mark.integration
async def test_sim_prints_its_port_and_info_reaches_it_from_another_process() -> None:
    sim = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "chassis_sdk.cli", "sim", "chassis",
        stdout=asyncio.subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        async with asyncio.timeout(10):
            port = (await sim.stdout.readline()).decode().strip()
        assert os.path.realpath(port).startswith("/dev/pts/")
        code, out, err = await run("-m", "chassis_sdk.cli", "info", port)
        assert code == 0, err
        assert "hardware     ZKWL-brush-motor-chassis" in out
        assert ": connected, OK" in out  # the diagnose() report
        assert "note   status REMOTE_OFFLINE" in out
        code, out, err = await run("-m", "chassis_sdk.cli", "monitor", port, "--seconds", "1.5")
        assert code == 0, err
        assert "REMOTE_OFFLINE" in out
        assert "faults" in out
        code, out, err = await run(
            "-m", "chassis_sdk.cli", "drive", port, "--linear", "0.2", "--duration", "0.3"
        )
        assert (code, out.splitlines()[-1]) == (0, "stopped"), err
    finally:
        sim.terminate()
        await sim.wait()


@pytest.mark.integration
@pytest.mark.parametrize(
    "command",
    ["", "demo", "ports", "sim", "info", "monitor", "drive", "record", "replay", "plot", "detect"],
)
async def test_help_on_every_command(command: str) -> None:
    code, out, _ = await run("-m", "chassis_sdk.cli", *([command] if command else []), "--help")
    assert code == 0
    assert out.startswith("usage: chassis-sdk")


def test_permission_denied_names_the_group_to_join() -> None:
    from chassis_sdk.core.transport import _describe_open_error

    exc = PermissionError(13, "Permission denied", "/dev/ttyUSB0")
    text = _describe_open_error("/dev/ttyUSB0", exc)
    assert "permission denied" in text
    assert "dialout" in text


@pytest.mark.integration
async def test_the_cli_page_documents_every_command_and_no_other() -> None:
    page = (ROOT / "docs" / "cli.md").read_text()
    documented = set(re.findall(r"^chassis-sdk ([\w-]+)", page, re.M))
    code, out, _ = await run("-m", "chassis_sdk.cli", "--help")
    assert code == 0
    listed = re.search(r"\{([\w,-]+)\}", out)
    commands = set(listed.group(1).split(",")) if listed else set()
    if not commands:  # argparse prints each command on its own line with metavar COMMAND
        commands = set(re.findall(r"^    ([\w-]+)\s", out, re.M))
    assert documented == commands
    for command in commands:
        assert f"**{command}**" in page, f"docs/cli.md says nothing of {command}"


def synopsis(page: str) -> dict[str, str]:
    """Each command's lines in the synopsis block at the top of docs/cli.md."""
    block = page.split("```text\n", 1)[1].split("```", 1)[0]
    found: dict[str, str] = {}
    current = None
    for line in block.splitlines():
        if line.startswith("chassis-sdk "):
            current = line.split()[1]
            found[current] = found.get(current, "") + line.split("#", 1)[0]
        elif current is not None and line.startswith(" "):
            found[current] += " " + line.split("#", 1)[0]
    return found


def test_the_cli_synopsis_names_every_option_of_every_command() -> None:
    from chassis_sdk.cli import build_parser
    from chassis_sdk.cli.profile import subparsers

    # Said once for all in the text below the block: -h, -b/--baudrate and --config.
    everywhere = {"help", "baudrate", "config"}
    lines = synopsis((ROOT / "docs" / "cli.md").read_text())
    for name, parser in subparsers(build_parser()).items():
        assert name in lines, f"docs/cli.md's synopsis has no line for {name}"
        for action in parser._actions:
            skip = action.dest in everywhere or action.help == argparse.SUPPRESS
            if skip or not action.option_strings:
                continue
            said = [
                o for o in action.option_strings if re.search(rf"{re.escape(o)}\b", lines[name])
            ]
            assert said, (name, action.option_strings)
