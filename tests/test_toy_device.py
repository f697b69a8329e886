"""A third device defined in one file (tests/support/toy_device.py), registered at run time or
installed through an entry point, works end to end with no edit to the SDK: lifetime,
watchdog and deadman, requests with timeouts, streams, events, the simulator server,
detect, record/replay/plot, sim and drive."""

from __future__ import annotations

import asyncio
import json
import math
import os
import random
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import chassis_sdk.devices as registry
from chassis_sdk import ConnectionState, EventKind, NotConnectedError, RequestTimeoutError
from chassis_sdk.cli import main as cli_main
from chassis_sdk.cli.devices import DeviceCommands, commands
from chassis_sdk.devices import DeviceProfile, profile, profiles, register, unregister
from chassis_sdk.recording import capture

from .support.cli import CLI, ROOT, cli
from .support.fuzz import harness, mutate
from .support.helpers import until
from .support.toy_device import PROFILE, Drive, Ping, Toy, ToyFirmware, ToySimulator, ToyTelemetry

TRANSPORTS = [pytest.param(None, id="pty"), pytest.param(0, id="tcp")]


@pytest.fixture
def toy() -> Iterator[DeviceProfile]:
    register(PROFILE)
    try:
        yield PROFILE
    finally:
        unregister("toy")


def drives(firmware: ToyFirmware) -> list[Drive]:
    return [c for _, c in firmware.received if isinstance(c, Drive)]


@pytest.mark.integration
@pytest.mark.usefixtures("toy")
@pytest.mark.parametrize("tcp_port", TRANSPORTS)
async def test_lifetime_streams_requests_events_and_odometry(tcp_port: int | None) -> None:
    booted_after = time.monotonic()
    async with ToySimulator(tcp_port=tcp_port) as sim:
        robot = Toy(sim.port, battery_low=13.0)
        async with robot:
            assert robot.connection_state is ConnectionState.CONNECTED
            events = robot.events()
            t = await anext(robot.telemetry())
            assert isinstance(t, ToyTelemetry)
            assert t.battery == pytest.approx(12.6)
            assert robot.latest_telemetry is not None
            uptime = await robot.ping()  # whole seconds since the toy booted
            assert 0 <= uptime <= time.monotonic() - booted_after
            low = await anext(events)
            assert low.kind is EventKind.BATTERY_LOW
            assert low.voltage == pytest.approx(12.6)
            assert robot.latest_odometry is not None
            frames = robot.telemetry()
        assert not robot.is_connected
        assert robot.connection_state.value == "disconnected"
        rest = [t async for t in frames]  # what was buffered, then the end: no hang
        assert all(isinstance(t, ToyTelemetry) for t in rest)
        assert robot.stats.frames > 0
        with pytest.raises(NotConnectedError):
            await robot.ping()


@pytest.mark.integration
@pytest.mark.usefixtures("toy")
async def test_watchdog_resends_and_the_deadman_writes_one_zero() -> None:
    async with ToySimulator() as sim, Toy(sim.port, command_timeout=0.3) as robot:
        await robot.set_velocity(0.4, 0.0)
        await until(lambda: robot.stats.command_expiries == 1)
        sent = drives(sim.firmware)
        await until(lambda: bool(drives(sim.firmware)) and drives(sim.firmware)[-1].linear_mm == 0)
        assert sum(d.linear_mm == 400 for d in sent) >= 4  # resent every 50 ms
        async for t in robot.telemetry():  # the toy stops, and nothing more is sent
            if t.speed == 0.0:
                break
        count = len(drives(sim.firmware))
        for _ in range(5):
            await anext(robot.telemetry())
        assert len(drives(sim.firmware)) == count
        assert drives(sim.firmware)[-1] == Drive(0, 0)


@pytest.mark.integration
@pytest.mark.usefixtures("toy")
@pytest.mark.parametrize("tcp_port", TRANSPORTS)
async def test_leaving_the_block_writes_zero_last(tcp_port: int | None) -> None:
    async with ToySimulator(tcp_port=tcp_port) as sim:
        async with Toy(sim.port) as robot:
            await robot.set_velocity(0.5, 0.2)
        await until(lambda: bool(drives(sim.firmware)) and drives(sim.firmware)[-1] == Drive(0, 0))
        assert drives(sim.firmware)[0] == Drive(500, 200)


@pytest.mark.integration
@pytest.mark.usefixtures("toy")
async def test_requests_retry_time_out_and_drop_late_replies() -> None:
    booted_after = time.monotonic()
    async with ToySimulator() as sim, Toy(sim.port, request_timeout=0.1, retries=1) as robot:
        sim.faults.reply_loss = 1.0
        with pytest.raises(RequestTimeoutError, match="ping"):
            await robot.ping()
        assert sum(isinstance(c, Ping) for _, c in sim.firmware.received) == 2
        sim.faults.reply_loss = 0.0
        sim.faults.reply_delay = 0.15
        robot.retries = 0
        with pytest.raises(RequestTimeoutError):
            await robot.ping()
        await until(lambda: robot.stats.late_replies == 1)
        sim.faults.reply_delay = 0.0
        uptime = await robot.ping()  # whole seconds since the toy booted
        assert 0 <= uptime <= time.monotonic() - booted_after


@pytest.mark.integration
@pytest.mark.usefixtures("toy")
async def test_a_bad_velocity_is_a_value_error_before_a_byte_is_written() -> None:
    async with ToySimulator() as sim, Toy(sim.port) as robot:
        for bad in (math.nan, math.inf, 40.0):
            with pytest.raises(ValueError, match="linear"):
                await robot.set_velocity(bad, 0.0)
        with pytest.raises(TypeError, match="linear"):  # a wrong type
            await robot.set_velocity(True, 0.0)
        await robot.ping()  # everything written before it has arrived
        assert drives(sim.firmware) == []


@pytest.mark.integration
@pytest.mark.usefixtures("toy")
async def test_detect_record_replay_and_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "toy.capture"
    async with ToySimulator() as sim:
        assert await capture.detect_device(sim.port, seconds=2.0) == "toy"
        cap = await capture.record(sim.port, path, seconds=0.3)
    assert cap.bytes > 0
    messages = [m for _, m in capture.decode_capture(path, "toy")]
    assert messages
    assert all(isinstance(m, ToyTelemetry) for m in messages)
    assert cli_main(["replay", str(path), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows[0]["type"] == "ToyTelemetry"
    assert rows[0]["battery"] == pytest.approx(12.6)
    png = tmp_path / "toy.png"
    assert cli_main(["plot", str(path), "-o", str(png)]) == 0  # the generic plot
    assert png.stat().st_size > 1000


def test_the_fuzz_harness_and_the_registry_see_it(toy: DeviceProfile) -> None:
    rng = random.Random(5)
    for target in ("toy", "toy-commands"):
        seeds = harness.seeds(target)
        for blob in seeds + [mutate(rng, rng.choice(seeds)) for _ in range(300)]:
            harness.check(target, blob)
    assert profile("toy") is toy
    assert list(profiles())[-1] == "toy"
    with pytest.raises(ValueError, match="already registered"):
        register(toy)
    with pytest.raises(ValueError, match="unknown device 'nope'; known: chassis, board, toy"):
        profile("nope")


def _install_entry_point(site: Path, value: str) -> None:
    """Make ``site`` hold a distribution that declares ``toy = value`` in the group."""
    info = site / "toy_device-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-device\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[chassis_sdk.devices]\ntoy = {value}\n")


def test_an_installed_entry_point_adds_the_device(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _install_entry_point(tmp_path, "tests.support.toy_device:PROFILE")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_installed", None)
    assert profiles()["toy"] is PROFILE
    assert "toy" not in registry._registered


def test_a_broken_entry_point_is_reported_and_skipped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    _install_entry_point(tmp_path, "tests.no_such_module:PROFILE")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_installed", None)
    assert list(profiles()) == ["chassis", "board"]
    assert "device entry point toy = tests.no_such_module:PROFILE failed" in caplog.text


@pytest.mark.integration
async def test_sim_detect_and_drive_from_the_command_line(tmp_path: Path) -> None:
    _install_entry_point(tmp_path, "tests.support.toy_device:PROFILE")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join((str(tmp_path), str(ROOT)))}
    sim = await asyncio.create_subprocess_exec(
        *CLI, "sim", "toy", "--tcp", "0",
        stdout=asyncio.subprocess.PIPE, env=env, cwd=ROOT,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        port = (await asyncio.wait_for(sim.stdout.readline(), 20)).decode().strip()
        assert port.startswith("socket://127.0.0.1:")
        code, out, err = await cli("detect", port, env=env, timeout=20)
        assert (code, out.strip()) == (0, "toy"), err
        code, out, err = await cli(
            "drive", port, "--protocol", "toy", "--linear", "0.2", "--duration", "0.3",
            env=env, timeout=20,
        )  # fmt: skip
        assert (code, out.splitlines()[-1]) == (0, "stopped"), err
        code, out, err = await cli("info", port, "--protocol", "toy", env=env, timeout=20)
        assert code == 0, err
        assert "toy: a toy differential base" in out
    finally:
        sim.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(sim.wait(), 10) == 128 + signal.SIGTERM


async def _toy_info(port: str, baudrate: int, timeout: float) -> None:
    """The toy's own ``info`` (what an installed package would bring)."""


TOY_COMMANDS = DeviceCommands(info=_toy_info)


def _install_commands(site: Path, value: str) -> None:
    """Make ``site`` hold a distribution that declares ``toy = value`` in the CLI's group."""
    info = site / "toy_cli-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-cli\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[chassis_sdk.cli]\ntoy = {value}\n")


@pytest.mark.usefixtures("toy")
def test_a_device_brings_its_own_commands_through_the_cli_entry_point_group(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert commands("toy").info is None  # none installed: the generic info serves
    _install_commands(tmp_path, "tests.test_toy_device:TOY_COMMANDS")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert commands("toy") is TOY_COMMANDS


@pytest.mark.usefixtures("toy")
def test_broken_commands_of_a_device_leave_the_generic_ones(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    _install_commands(tmp_path, "tests.no_such_module:COMMANDS")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert commands("toy").info is None
    assert "commands of device 'toy' failed to load" in caplog.text
