"""The simulators' runtime commands: the parser as a table (sans-IO, an injected clock),
what each command does to the firmware model, the standard-input reader of
``chassis-sdk sim``, and the command end to end (a subprocess taking ``bumper front`` on
its stdin while ``chassis-sdk info`` sees the bumper)."""

from __future__ import annotations

import asyncio
import math
import os
from collections.abc import Callable

import anyio
import pytest

from chassis_sdk.cli.sim_command import MAX_LINE, _lines
from chassis_sdk.protocol import (
    BoardDecoder,
    BoardEncoder,
    ChassisDecoder,
    ChassisEncoder,
    DriverError,
    ImuSample,
    Telemetry,
    VelocityCommand,
)
from chassis_sdk.sim import BoardFirmware, ChassisFirmware, World
from chassis_sdk.sim.control import COMMANDS, apply, help_line

from .support.cli import CLI, ROOT

NOW = 1000.0
Firmware = ChassisFirmware | BoardFirmware


def _make(device: str) -> Firmware:
    return ChassisFirmware() if device == "chassis" else BoardFirmware()


@pytest.mark.parametrize(
    ("device", "before", "line", "answer", "effect"),
    [
        pytest.param("chassis", [], "bumper front", "ok: front bumper pressed (latched until clear-faults)",
                     lambda fw: fw.front_bumper and not fw.bumpers_held[0], id="bumper-front"),
        pytest.param("chassis", [], "Bumper REAR", "ok: rear bumper pressed (latched until clear-faults)",
                     lambda fw: fw.rear_bumper and not fw.front_bumper, id="bumper-rear-any-case"),
        pytest.param("chassis", [], "bumper front hold",
                     "ok: front bumper held pressed (clear-faults cannot clear it; 'bumper front off')",
                     lambda fw: fw.front_bumper and fw.bumpers_held[0], id="bumper-hold"),
        pytest.param("chassis", ["bumper rear hold"], "bumper rear off",
                     "ok: rear bumper released and its latch cleared",
                     lambda fw: not fw.rear_bumper and not fw.bumpers_held[1], id="bumper-off"),
        pytest.param("chassis", [], "bumper", "error: usage: bumper front|rear [hold|off]",
                     lambda fw: not fw.front_bumper, id="bumper-no-side"),
        pytest.param("chassis", [], "bumper left", "error: usage: bumper front|rear [hold|off]",
                     lambda fw: not fw.front_bumper, id="bumper-bad-side"),
        pytest.param("chassis", [], "bumper front sideways", "error: usage: bumper front|rear [hold|off]",
                     lambda fw: not fw.front_bumper, id="bumper-bad-action"),
        pytest.param("chassis", [], "estop on", "ok: hardware e-stop pressed",
                     lambda fw: fw.hardware_estop, id="estop-on"),
        pytest.param("chassis", ["estop on"], "estop off", "ok: hardware e-stop released",
                     lambda fw: not fw.hardware_estop, id="estop-off"),
        pytest.param("chassis", [], "estop on remote", "ok: remote e-stop pressed",
                     lambda fw: fw.remote_estop and not fw.hardware_estop, id="estop-remote"),
        pytest.param("chassis", [], "estop maybe", "error: usage: estop on|off [hardware|remote]",
                     lambda fw: not fw.hardware_estop, id="estop-bad"),
        pytest.param("chassis", [], "battery 21.0", "ok: battery at 21 V (open circuit; it sags under load)",
                     lambda fw: abs(fw.battery_voltage - 21.0) < 0.1, id="battery"),
        pytest.param("board", [], "battery 10.5", "ok: battery at 10.5 V (open circuit; it sags under load)",
                     lambda fw: abs(fw.battery_voltage - 10.5) < 0.1, id="battery-board"),
        pytest.param("chassis", [], "battery full", "error: battery must be a number, got 'full'",
                     lambda fw: fw.battery_voltage > 25, id="battery-not-a-number"),
        pytest.param("chassis", [], "battery 500", "error: battery must be a finite number 0 to 100 V, got 500.0",
                     lambda fw: fw.battery_voltage > 25, id="battery-out-of-range"),
        pytest.param("chassis", [], "battery nan", "error: battery must be finite, got nan",
                     lambda fw: fw.battery_voltage > 25, id="battery-nan"),
        pytest.param("chassis", [], "battery", "error: usage: battery VOLTS",
                     lambda fw: True, id="battery-missing"),
        pytest.param("chassis", [], "driver-fault FL", "ok: FL driver fault OVER_CURRENT (latched until clear-faults)",
                     lambda fw: fw.driver_errors[0] == DriverError.OVER_CURRENT, id="driver-fault"),
        pytest.param("chassis", [], "driver-fault rr hall_sensor",
                     "ok: RR driver fault HALL_SENSOR (latched until clear-faults)",
                     lambda fw: fw.driver_errors[3] == DriverError.HALL_SENSOR, id="driver-fault-named"),
        pytest.param("chassis", ["driver-fault FR"], "driver-fault FR off", "ok: FR driver's errors cleared",
                     lambda fw: not any(fw.driver_errors), id="driver-fault-off"),
        pytest.param("chassis", [], "driver-fault XX", "error: usage: driver-fault FL|FR|RL|RR [off|ERROR]",
                     lambda fw: not any(fw.driver_errors), id="driver-fault-bad-wheel"),
        pytest.param("chassis", [], "driver-fault FL gremlins",
                     "error: unknown driver error 'gremlins' (known: under_voltage, position_error,",
                     lambda fw: not any(fw.driver_errors), id="driver-fault-bad-error"),
        pytest.param("chassis", [], "stall 2", "ok: wheels stalled for 2 s (commanded, not turning)",
                     lambda fw: fw.stalled(NOW + 1.99) and not fw.stalled(NOW + 2.0), id="stall"),
        pytest.param("board", [], "stall 0.5", "ok: wheels stalled for 0.5 s (commanded, not turning)",
                     lambda fw: fw.stalled(NOW + 0.4), id="stall-board"),
        pytest.param("chassis", ["stall 2"], "stall off", "ok: wheels free",
                     lambda fw: not fw.stalled(NOW), id="stall-off"),
        pytest.param("chassis", [], "stall -1", "error: stall must be a finite number 0 to 3600 s, got -1.0",
                     lambda fw: not fw.stalled(NOW), id="stall-negative"),
        pytest.param("board", [], "tilt 30", "ok: board tilted 30° (pitch); the IMU shows it",
                     lambda fw: fw.tilt == (30.0, 0.0), id="tilt"),
        pytest.param("board", [], "tilt -12.5 roll", "ok: board tilted -12.5° (roll); the IMU shows it",
                     lambda fw: fw.tilt == (0.0, -12.5), id="tilt-roll"),
        pytest.param("board", ["tilt 30"], "tilt off", "ok: board level",
                     lambda fw: fw.tilt == (0.0, 0.0), id="tilt-off"),
        pytest.param("board", [], "tilt 30 yaw", "error: usage: tilt DEGREES|off [pitch|roll]",
                     lambda fw: fw.tilt == (0.0, 0.0), id="tilt-bad-axis"),
        pytest.param("board", [], "tilt 95", "error: tilt must be a finite number -90 to 90 °, got 95.0",
                     lambda fw: fw.tilt == (0.0, 0.0), id="tilt-too-far"),
        pytest.param("chassis", [], "tilt 30", "error: tilt does not apply to the chassis (it has no IMU)",
                     lambda fw: True, id="tilt-on-a-chassis"),
        pytest.param("board", [], "bumper front", "error: bumper does not apply to the board (it has no bumpers)",
                     lambda fw: True, id="bumper-on-a-board"),
        pytest.param("board", [], "estop on", "error: estop does not apply to the board (it has no e-stop button)",
                     lambda fw: True, id="estop-on-a-board"),
        pytest.param("board", [], "driver-fault FL",
                     "error: driver-fault does not apply to the board (it has no motor drivers to ask)",
                     lambda fw: True, id="driver-fault-on-a-board"),
        pytest.param("chassis", [], "reset", "ok: firmware rebooting (silent for 0.5 s)",
                     lambda fw: fw.resets == 1 and fw.booting(NOW + 0.4), id="reset"),
        pytest.param("chassis", [], "status",
                     "ok: true pose x=0.000 m y=0.000 m heading=0.0°; status REMOTE_OFFLINE; battery 27.",
                     lambda fw: True, id="status-chassis"),
        pytest.param("board", ["tilt 10"], "status",
                     "ok: true pose x=0.000 m y=0.000 m heading=0.0°; tilt pitch 10° roll 0°; battery 12.",
                     lambda fw: True, id="status-board"),
        pytest.param("chassis", [], "frobnicate now", "error: unknown command 'frobnicate'; try help",
                     lambda fw: True, id="unknown"),
        pytest.param("chassis", [], "", "", lambda fw: True, id="blank"),
        pytest.param("chassis", [], "   # a comment", "", lambda fw: True, id="comment"),
        pytest.param("chassis", [], "estop on  # and a comment", "ok: hardware e-stop pressed",
                     lambda fw: fw.hardware_estop, id="trailing-comment"),
        pytest.param("chassis", [], "\x00\xff bumper", "error: unknown command '\\x00ÿ'; try help",
                     lambda fw: not fw.front_bumper, id="binary"),
    ],
)  # fmt: skip
def test_each_command_answers_one_line_and_does_what_it_says(
    device: str, before: list[str], line: str, answer: str, effect: Callable[[Firmware], object]
) -> None:
    fw = _make(device)
    for earlier in before:
        assert apply(fw, earlier, NOW).startswith("ok: ")
    got = apply(fw, line, NOW)
    assert got.startswith(answer), got
    assert "\n" not in got
    assert effect(fw)


@pytest.mark.parametrize("device", ["chassis", "board"])
def test_help_lists_what_applies_to_the_device_in_one_line(device: str) -> None:
    fw = _make(device)
    got = apply(fw, "help", NOW)
    assert got == f"ok: {help_line(fw)}"
    assert "\n" not in got
    for name, command in COMMANDS.items():
        applies = isinstance(fw, command.devices)
        assert (command.usage in got) is applies, name
        answer = apply(fw, name, NOW)  # without its arguments
        assert not answer.startswith("error: unknown command"), answer
        assert answer.startswith(("error: usage: ", "ok: ")) or not applies


class _Toy:
    """A firmware model that is neither a chassis nor a board."""

    def receive(self, data: bytes, now: float) -> bytes:
        return b""

    def poll(self, now: float) -> bytes:
        return b""

    def next_deadline(self) -> float:
        return 0.0

    def on_connect(self, now: float) -> None:
        pass

    def reset(self, now: float, downtime: float = 0.5) -> None:
        pass


def test_another_device_takes_only_help() -> None:
    assert apply(_Toy(), "help", NOW) == "ok: commands: help"
    assert apply(_Toy(), "bumper front", NOW) == (
        "error: bumper does not apply to this device's simulator (it has no bumpers)"
    )


@pytest.mark.parametrize(
    "line",
    ["bumper front rear extra", "stall", "stall inf", "stall 1e400", "tilt", "battery -1",
     "reset -1", "reset 1 2", "status now", "driver-fault", "driver-fault FL off on", "x" * 5000,
     "estop", "estop on hardware extra"],
)  # fmt: skip
@pytest.mark.parametrize("device", ["chassis", "board"])
def test_no_line_raises_or_ends_anything(device: str, line: str) -> None:
    got = apply(_make(device), line, NOW)
    assert got.startswith("error: "), got
    assert "\n" not in got


# --- what the commands do to the physics (sans-IO, an injected clock) --------------------


def test_a_stall_holds_the_chassis_wheels_while_commanded_then_frees_them() -> None:
    fw = ChassisFirmware()
    encoder, decoder = ChassisEncoder(), ChassisDecoder()
    now = NOW
    fw.on_connect(now)
    assert apply(fw, "stall 1", now).startswith("ok: ")
    speeds: list[float] = []
    for _ in range(100):  # 2 s at 50 Hz, commanding 0.3 m/s all along
        now += 0.02
        fw.receive(encoder.drive_velocity(0.3, 0.0), now)
        speeds += [m.linear for m in decoder.feed(fw.poll(now)) if isinstance(m, Telemetry)]
    stalled, free = speeds[:49], speeds[52:]
    assert stalled == [0.0] * len(stalled)
    assert free[-1] == pytest.approx(0.3)
    assert fw.true_pose[0] == pytest.approx(sum(speeds) * 0.02, rel=0.05)  # no motion while held


def test_a_stalled_chassis_draws_stall_current() -> None:
    fw = ChassisFirmware()
    fw.on_connect(NOW)
    fw.receive(ChassisEncoder().drive_velocity(0.5, 0.0), NOW)
    apply(fw, "stall 5", NOW)
    fw.poll(NOW + 0.02)
    assert fw.wheels == [0.0] * 4
    assert min(fw.power().currents) > 3.0


@pytest.mark.parametrize(
    ("line", "x", "y", "z"),
    [
        pytest.param("tilt 30", 0.5, 0.0, math.cos(math.radians(30)), id="pitch"),
        pytest.param("tilt 30 roll", 0.0, 0.5, math.cos(math.radians(30)), id="roll"),
        pytest.param("tilt off", 0.0, 0.0, 1.0, id="level"),
    ],
)
def test_a_tilted_board_s_accelerometer_shows_gravity_off_z(
    line: str, x: float, y: float, z: float
) -> None:
    fw = BoardFirmware()
    apply(fw, line, NOW)
    sample = fw.imu_sample()
    assert sample.accel.x == pytest.approx(x, abs=0.03)
    assert sample.accel.y == pytest.approx(y, abs=0.03)
    assert sample.accel.z == pytest.approx(z, abs=0.03)
    tilt = math.degrees(math.acos(sample.accel.z / math.dist((0, 0, 0), tuple(sample.accel))))
    assert tilt == pytest.approx(0 if line == "tilt off" else 30, abs=2)


def test_a_stalled_board_reports_no_speed_while_commanded() -> None:
    fw = BoardFirmware(world=World.arena(4, 4))
    encoder, decoder = BoardEncoder(), BoardDecoder()
    now = NOW
    fw.on_connect(now)
    apply(fw, "stall 1", now)
    x_before = fw.true_pose[0]
    for _ in range(50):
        now += 0.01
        fw.receive(encoder.encode(VelocityCommand(300, 0)), now)
        for message in decoder.feed(fw.poll(now)):
            assert not isinstance(message, ImuSample) or message.accel.x > -0.5
    assert fw.linear == 0.0
    assert fw.true_pose[0] == x_before


# --- the standard-input reader -------------------------------------------------------------


async def _read_all(data: bytes) -> list[str | None]:
    read, write = os.pipe()
    try:
        os.write(write, data)
        os.close(write)
        with anyio.fail_after(5):
            return [line async for line in _lines(read, terminal=False)]
    finally:
        os.close(read)


@pytest.mark.parametrize(
    ("data", "lines"),
    [
        pytest.param(b"bumper front\nstall 2\n", ["bumper front", "stall 2"], id="lines"),
        pytest.param(b"help", ["help"], id="no-final-newline"),
        pytest.param(b"a\r\nb\n", ["a\r", "b"], id="crlf-kept-for-the-parser"),
        pytest.param(b"\xff\xfe\n", ["\ufffd\ufffd"], id="not-utf8"),
        pytest.param(b"x" * (MAX_LINE + 1) + b"\nhelp\n", [None, "help"], id="overlong"),
        pytest.param(b"y" * (3 * 4096) + b"\nhelp\n", [None, "help"], id="overlong-chunks"),
        pytest.param(b"", [], id="empty"),
    ],
)
async def test_the_reader_yields_lines_until_the_end(data: bytes, lines: list[str | None]) -> None:
    assert await _read_all(data) == lines


async def test_dev_null_ends_the_reader_at_once() -> None:
    fd = os.open(os.devnull, os.O_RDONLY)
    try:
        with anyio.fail_after(5):
            assert [line async for line in _lines(fd, terminal=False)] == []
    finally:
        os.close(fd)


# --- end to end --------------------------------------------------------------------------------


async def _run(*args: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        *CLI, *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    with anyio.fail_after(30):
        out, err = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


@pytest.mark.integration
async def test_sim_takes_commands_on_stdin_and_info_sees_them() -> None:
    sim = await asyncio.create_subprocess_exec(
        *CLI, "sim", "chassis", "--world", "arena:4x3",
        stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    assert sim.stdin is not None
    assert sim.stdout is not None
    try:
        with anyio.fail_after(15):
            port = (await sim.stdout.readline()).decode().strip()
            running = (await sim.stdout.readline()).decode()
            assert "in a world of 4 walls" in running
            sim.stdin.write(b"frobnicate\nbumper front\n")
            await sim.stdin.drain()
            assert (await sim.stdout.readline()).decode().startswith("error: unknown command")
            assert (await sim.stdout.readline()).decode() == (
                "ok: front bumper pressed (latched until clear-faults)\n"
            )
        code, out, err = await _run("info", port)
        assert "FRONT_BUMPER" in out + err
        assert code == 4  # a latched bumper is a fault (EXIT_FAULT)
        sim.stdin.close()  # the end of input is not the end of the simulator
        code, out, err = await _run("info", port)
        assert "FRONT_BUMPER" in out + err
        assert sim.returncode is None
    finally:
        sim.terminate()
        await sim.wait()


@pytest.mark.integration
async def test_sim_with_stdin_at_dev_null_runs_on() -> None:
    sim = await asyncio.create_subprocess_exec(
        *CLI, "sim", "board",
        stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    assert sim.stdout is not None
    try:
        with anyio.fail_after(15):
            port = (await sim.stdout.readline()).decode().strip()
        code, _out, err = await _run("info", port, "--device", "board")
        assert code == 0, err
        assert sim.returncode is None
    finally:
        sim.terminate()
        await sim.wait()


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "code", "why"),
    [
        pytest.param(("--world", "arena:4"), 2, "argument --world: bad world 'arena:4'", id="bad-spec"),
        pytest.param(("--world", "arena:0.5x0.5"), 1, "touches a wall of this world", id="too-small"),
    ],
)  # fmt: skip
async def test_a_bad_world_is_one_line(args: tuple[str, ...], code: int, why: str) -> None:
    got, out, err = await _run("sim", "chassis", *args)
    assert (got, out) == (code, "")
    assert why in err.strip().splitlines()[-1]
    assert "Traceback" not in err
