"""``chassis_sdk.sync``: the blocking API, against the simulators on ptys.

In this process (plain test functions, the simulator in its own loop thread through
``sync.Simulator``): blocking calls, iterators and their closing, timeouts, wrong
arguments before any byte, a twin for every public member, a Jupyter-like running
loop, the link lost, garbage collection. In subprocesses (the simulator in the test's
loop, so it watches a script that blocks or dies): the deadman while the script sleeps,
Ctrl-C in a blocking call, SIGTERM, SIGKILL, the interpreter's exit and an exception.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import inspect
import signal
import sys
import threading
import time
from collections.abc import AsyncIterator, Iterator

import pytest

from chassis_sdk import (
    Board,
    Chassis,
    ChassisError,
    ChassisInfo,
    ConnectionLostError,
    NotConnectedError,
    RequestTimeoutError,
    Telemetry,
    sync,
)
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.cli import ROOT, silent_pty
from .support.helpers import until, wait_until


def drives(firmware: object) -> list[tuple[float, DriveVelocity]]:
    """The 0x02 linear-mode frames the simulated firmware received, with arrival times."""
    received = list(firmware.received)  # type: ignore[attr-defined]
    return [(t, c) for t, c in received if isinstance(c, DriveVelocity)]


def is_zero(c: DriveVelocity) -> bool:
    return c.linear_mm == 0 and c.angular == 0.0


@pytest.fixture
def sim() -> Iterator[sync.Simulator]:
    with sync.Simulator("chassis") as s:
        yield s


@pytest.fixture
def board_sim() -> Iterator[sync.Simulator]:
    with sync.Simulator("board") as s:
        yield s


def sync_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("chassis_sdk.sync /")]


# --- blocking calls --------------------------------------------------------------------------


@pytest.mark.integration
def test_blocking_calls_return_what_the_device_answers(sim: sync.Simulator) -> None:
    with sync.Chassis(sim.port) as robot:
        robot.verify()
        assert robot.get_firmware_version() == 103
        info = robot.get_chassis_info()
        assert isinstance(info, ChassisInfo)
        assert info.track_width == pytest.approx(0.725)
        assert str(robot.get_ship_date()) == "2024-01-02"
        assert robot.get_hardware_version()
        assert robot.diagnose().ok
        assert robot.is_connected
        assert robot.sequence_scheme in (None, "shared", "per-id")  # a generated twin
        robot.configure_odometry("wheels", track_width=0.7)  # a generated coroutine twin
    assert not robot.is_connected
    assert sync_threads() == []  # the loop thread is gone


@pytest.mark.integration
def test_board_requests_and_streams(board_sim: sync.Simulator) -> None:
    with sync.Board(board_sim.port) as board:
        assert board.set_led(True) is True
        assert board.get_led() is True
        assert board.set_buzzer(False) is False
        for sample in board.imu():
            assert sample.accel is not None
            break
        battery = next(iter(board.battery(timeout=2.0)))
        assert battery.voltage > 0


@pytest.mark.integration
def test_set_velocity_moves_the_robot_and_stop_writes_zero(sim: sync.Simulator) -> None:
    with sync.Chassis(sim.port) as robot:
        robot.set_velocity(0.3, 0.0, duration=5.0)
        t = robot.wait_for(lambda t: t.linear > 0.2, timeout=3.0)
        assert isinstance(t, Telemetry)
        robot.stop()
        wait_until(lambda: bool(drives(sim.firmware)) and is_zero(drives(sim.firmware)[-1][1]))
        assert robot.commanded_velocity is None


@pytest.mark.integration
@pytest.mark.timing
def test_deadman_stops_while_the_caller_blocks(sim: sync.Simulator) -> None:
    with sync.Chassis(sim.port, command_timeout=0.3) as robot:
        robot.set_velocity(0.3, 0.0)
        start = time.monotonic()
        time.sleep(0.6)  # the caller blocks: the deadman runs in the loop thread
        zeros = [t for t, c in drives(sim.firmware) if is_zero(c)]
        assert zeros, "no zero while the caller slept"
        assert 0.25 <= zeros[0] - start <= 0.5, zeros[0] - start
        assert robot.commanded_velocity is None


@pytest.mark.integration
def test_open_and_close_without_with_and_again(sim: sync.Simulator) -> None:
    robot = sync.Chassis(sim.port).open()
    try:
        assert robot.get_firmware_version() == 103
        with pytest.raises(ChassisError, match="already open"):
            robot.open()
    finally:
        robot.close()
    robot.close()  # twice is fine
    with pytest.raises(NotConnectedError, match="not open"):
        robot.get_firmware_version()
    assert robot.open() is robot  # and again
    robot.close()


@pytest.mark.integration
def test_open_by_name_and_by_class(sim: sync.Simulator) -> None:
    assert sync.blocking_class("chassis") is sync.Chassis
    assert sync.blocking_class(Board) is sync.Board
    with pytest.raises(ValueError, match="unknown device"):
        sync.blocking_class("toaster")
    with pytest.raises(TypeError, match="device name or a Device class"):
        sync.blocking_class(int)  # type: ignore[arg-type]
    with sync.open("chassis", sim.port, request_timeout=0.5) as robot:
        assert robot.get_firmware_version() == 103
        assert robot.default_timeout == pytest.approx(0.5 * 3 + sync.MARGIN)


# --- iterators ------------------------------------------------------------------------------


def subscribers(robot: sync.Chassis) -> int:
    """Subscribers of the telemetry stream, counted in the loop thread."""
    return robot.portal.call(lambda: len(robot.device._telemetry))


@pytest.mark.integration
def test_breaking_out_of_a_loop_unsubscribes_in_the_loop(sim: sync.Simulator) -> None:
    with sync.Chassis(sim.port) as robot:
        seqs = []
        for t in robot.telemetry():
            seqs.append(t.seq)
            if len(seqs) == 5:
                break
        assert len(set(seqs)) == 5
        assert subscribers(robot) == 0
        held = robot.telemetry()
        next(held)
        assert subscribers(robot) == 1
        held.close()
        assert subscribers(robot) == 0
        with pytest.raises(StopIteration):
            next(held)
        with robot.telemetry() as it:
            next(it)
            assert subscribers(robot) == 1
        assert subscribers(robot) == 0


@pytest.mark.integration
def test_an_iterator_ends_when_its_device_closes(sim: sync.Simulator) -> None:
    robot = sync.Chassis(sim.port).open()
    it = robot.telemetry()
    next(it)
    robot.close()
    assert list(it) == []


# --- timeouts -----------------------------------------------------------------------------------


@pytest.mark.integration
@pytest.mark.timing
def test_a_call_that_cannot_complete_times_out_in_time() -> None:
    with silent_pty() as port, sync.Chassis(port, request_timeout=5.0, link_timeout=None) as robot:
        start = time.monotonic()
        with pytest.raises(RequestTimeoutError, match="within 0.3 s"):
            robot.get_firmware_version(timeout=0.3)
        assert 0.3 <= time.monotonic() - start < 0.8
        start = time.monotonic()
        with pytest.raises(RequestTimeoutError):
            next(robot.telemetry(timeout=0.2))
        assert 0.2 <= time.monotonic() - start < 0.7
        with pytest.raises(RequestTimeoutError):
            robot.verify(timeout=0.2)  # its own timeout keeps its meaning
        assert robot.is_connected  # a timeout leaves the device usable


@pytest.mark.integration
@pytest.mark.timing
def test_the_default_bound_is_the_requests_own() -> None:
    with silent_pty() as port, sync.Chassis(port, request_timeout=0.1, retries=1) as robot:
        start = time.monotonic()
        with pytest.raises(RequestTimeoutError, match="FIRMWARE_VERSION"):
            robot.get_firmware_version()  # the device's own timeout, not the wrapper's
        assert time.monotonic() - start < 0.2 * 2 + sync.MARGIN


# --- wrong arguments ------------------------------------------------------------------------


@pytest.mark.integration
def test_wrong_arguments_raise_before_any_byte(sim: sync.Simulator) -> None:
    threads = threading.active_count()
    with pytest.raises(ValueError, match="command_timeout"):
        sync.Chassis(sim.port, command_timeout=-1.0)
    with pytest.raises(TypeError, match="stop_on_signals"):
        sync.Chassis(sim.port, stop_on_signals="yes")  # type: ignore[arg-type]
    assert threading.active_count() == threads  # nothing was started
    with sync.Chassis(sim.port) as robot:
        robot.verify()
        before = len(sim.firmware.received)
        with pytest.raises(ValueError, match="finite"):
            robot.set_velocity(float("nan"), 0.0)
        # A wrong type: TypeError by DESIGN (core.validation said ValueError until issue 27)
        with pytest.raises((TypeError, ValueError), match="linear must be a number"):
            robot.set_velocity("fast", 0.0)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="timeout"):
            robot.get_firmware_version(timeout=-1.0)
        with pytest.raises((TypeError, ValueError), match="timeout must be a number"):
            robot.stop(timeout="1")  # type: ignore[arg-type]
        with pytest.raises(TypeError):
            robot.get_chassis_info(1)  # type: ignore[call-arg]
        with pytest.raises(TypeError):
            robot.configure_odometry("wheels", bogus=1)  # a generated twin binds first
        with pytest.raises(ValueError, match="source"):
            robot.configure_odometry("compass")
        with pytest.raises(ValueError, match="timeout"):
            robot.emergency_stop(confirm=True, timeout=float("inf"))
        robot.get_firmware_version()  # a round trip: anything written before it has arrived
        wait_until(lambda: len(sim.firmware.received) > before)
        new = [c for _, c in list(sim.firmware.received)[before:]]
        assert len(new) == 1, new  # only the round trip's request
        assert not isinstance(new[0], DriveVelocity)


def test_calls_on_a_closed_device_say_so() -> None:
    robot = sync.Chassis("/dev/ttyDOESNOTEXIST")
    assert robot.is_connected is False  # read directly: no loop runs
    assert robot.command_timeout == 0.5
    with pytest.raises(NotConnectedError, match="not open"):
        robot.stop()
    with pytest.raises(NotConnectedError, match="not open"):
        robot.telemetry()
    with pytest.raises(ChassisError, match="no such device"):
        robot.open()
    assert sync_threads() == []  # a failed open leaves no thread


# --- a twin for every public member ---------------------------------------------------------------


def public(cls: type) -> dict[str, object]:
    return {
        n: inspect.getattr_static(cls, n)
        for n in dir(cls)
        if not n.startswith("_")
        and (
            isinstance(inspect.getattr_static(cls, n), property)
            or inspect.isfunction(inspect.getattr_static(cls, n))
        )
    }


@pytest.mark.parametrize(
    ("async_cls", "sync_cls"),
    [(Chassis, sync.Chassis), (Board, sync.Board)],
    ids=["chassis", "board"],
)
def test_every_public_member_has_a_blocking_twin(async_cls: type, sync_cls: type) -> None:
    members = public(async_cls)
    assert len(members) > 40
    coroutines = [n for n, m in members.items() if inspect.iscoroutinefunction(m)]
    assert {"set_velocity", "stop", "verify", "diagnose"} <= set(coroutines)
    for name, member in members.items():
        twin = inspect.getattr_static(sync_cls, name)
        if isinstance(member, property):
            assert isinstance(twin, property), name
            assert (twin.fset is None) == (member.fset is None), name
            assert twin.__doc__ == member.__doc__, name
            continue
        assert callable(twin), name
        assert not inspect.iscoroutinefunction(twin), name
        if name in ("connect", "close"):
            continue  # the blocking lifetime (open/close) has its own
        assert (twin.__doc__ or "").startswith(member.__doc__ or ""), name
        params = dict(inspect.signature(member).parameters)  # type: ignore[arg-type]
        theirs = dict(inspect.signature(twin).parameters)
        params.setdefault(
            "timeout", inspect.Parameter("timeout", inspect.Parameter.KEYWORD_ONLY, default=None)
        )
        assert list(theirs) == list(params), name
        for p in params:
            assert theirs[p].kind == params[p].kind, (name, p)
            assert theirs[p].default == params[p].default, (name, p)


# --- a Jupyter-like running loop --------------------------------------------------------------------


@pytest.mark.integration
def test_calls_from_inside_a_running_event_loop(sim: sync.Simulator) -> None:
    """A notebook cell runs in a thread whose loop is running: the blocking API works
    there (it blocks that loop while it waits, as the caller chose)."""
    results: list[object] = []

    def cell() -> None:  # what Jupyter runs, synchronously, with its loop running
        assert asyncio.get_running_loop() is not None
        with sync.Chassis(sim.port) as robot:
            results.append(robot.get_firmware_version())
            robot.set_velocity(0.2, 0.0, duration=0.2)
            results.append(next(iter(robot.telemetry())).seq >= 0)
            robot.stop()

    async def notebook() -> None:
        cell()  # called synchronously from a coroutine
        loop = asyncio.get_running_loop()
        done = loop.create_future()

        def callback() -> None:  # from a loop callback
            cell()
            done.set_result(None)

        loop.call_soon(callback)
        await done
        robot = sync.Chassis(sim.port).open()  # a cell that leaves it open for the next
        results.append(robot.get_hardware_version() != "")
        robot.close()

    asyncio.run(notebook())
    assert results == [103, True, 103, True, True]


# --- the link lost, garbage collection --------------------------------------------------------------


@pytest.mark.integration
def test_the_link_lost_raises_in_the_iterator_and_the_call(sim: sync.Simulator) -> None:
    with sync.Chassis(sim.port) as robot:
        it = robot.telemetry(timeout=3.0)
        next(it)
        sim.portal.call(sim.server.unplug)
        with pytest.raises(ConnectionLostError):
            for _ in it:
                pass
        with pytest.raises((ConnectionLostError, NotConnectedError)):
            robot.get_firmware_version()


@pytest.mark.integration
def test_dropping_an_open_device_stops_the_robot(sim: sync.Simulator) -> None:
    robot = sync.Chassis(sim.port).open()
    robot.set_velocity(0.3, 0.0, duration=30.0)
    wait_until(lambda: any(not is_zero(c) for _, c in drives(sim.firmware)))
    del robot
    gc.collect()
    assert sync_threads() == []  # closed, and its loop thread ended
    # The zero left before the thread ended; the simulator's thread reads it from the pty.
    wait_until(lambda: is_zero(drives(sim.firmware)[-1][1]), timeout=1.0)


# --- scripts that block, are interrupted, or die (in subprocesses) ---------------------------------

DRIVING = """
import sys, time
from chassis_sdk import sync
with sync.Chassis(sys.argv[1]) as robot:
    robot.verify()
    print("driving", flush=True)
    while True:  # a control loop: keep calling, as with cmd_vel
        robot.set_velocity(0.3, 0.0)
        time.sleep(0.05)
"""

SLEEPING = """
import sys, time
from chassis_sdk import sync
with sync.Chassis(sys.argv[1]) as robot:
    robot.set_velocity(0.3, 0.0)
    print("sent", flush=True)
    time.sleep(30)  # blocks past the deadman
"""

INTERRUPTED = """
import sys
from chassis_sdk import sync
robot = sync.Chassis(sys.argv[1]).open()
robot.set_velocity(0.3, 0.0, duration=30.0)
robot.wait_for(lambda t: t.linear > 0.2, timeout=5.0)
seen = []
def never(t):  # runs in the loop thread while the main thread waits in wait_for
    if not seen:
        seen.append(t)
        print("waiting", flush=True)
    return False
try:
    robot.wait_for(never, timeout=30.0)  # a blocking call, Ctrl-C'd
except KeyboardInterrupt:
    print("interrupted", robot.commanded_velocity, flush=True)
    raise
"""

EXITING = """
import sys
from chassis_sdk import sync
robot = sync.Chassis(sys.argv[1]).open()  # never closed by the script
robot.set_velocity(0.3, 0.0, duration=30.0)
robot.wait_for(lambda t: t.linear > 0.2, timeout=5.0)
print("moving", flush=True)
if sys.argv[2] == "exception":
    raise RuntimeError("the script failed")
"""


@contextlib.asynccontextmanager
async def script(program: str, *args: str) -> AsyncIterator[asyncio.subprocess.Process]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", program, *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    try:
        yield proc
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


async def line(proc: asyncio.subprocess.Process, timeout: float = 15.0) -> str:
    assert proc.stdout is not None
    async with asyncio.timeout(timeout):
        text = (await proc.stdout.readline()).decode()
    if not text:
        assert proc.stderr is not None
        raise AssertionError(f"ended: {(await proc.stderr.read()).decode()}")
    return text.strip()


def moving(sim: ChassisSimulator) -> bool:
    return all(w > 0.2 for w in sim.firmware.wheels)


def still(sim: ChassisSimulator) -> bool:
    return all(abs(w) < 1e-3 for w in sim.firmware.wheels)


@pytest.mark.integration
@pytest.mark.timing
async def test_a_script_that_sleeps_past_the_deadman_stops_the_robot() -> None:
    async with ChassisSimulator() as sim, script(SLEEPING, sim.port) as proc:
        assert await line(proc) == "sent"
        await until(lambda: any(is_zero(c) for _, c in drives(sim.firmware)))
        frames = drives(sim.firmware)
        first = next(t for t, c in frames if not is_zero(c))
        zero = next(t for t, c in frames if is_zero(c))
        print(f"deadman: zero {zero - first:.3f} s after the command, the script asleep")
        assert 0.45 <= zero - first <= 0.5 + 0.15, zero - first  # command_timeout 0.5 s
        assert proc.returncode is None  # still asleep: the deadman did it
        await until(lambda: still(sim), timeout=3.0)


READING = """
import signal, sys, threading, time
from chassis_sdk import sync
robot = sync.Chassis(sys.argv[1]).open()  # a notebook's way: no `with`
robot.set_velocity(0.3, 0.0, duration=30.0)
robot.wait_for(lambda t: t.linear > 0.2, timeout=5.0)
main = threading.main_thread().ident
arrived = threading.Event()

def ctrl_c(signum, frame):  # Python's own, which also says it arrived
    arrived.set()
    raise KeyboardInterrupt

def in_the_read():
    frame = sys._current_frames().get(main)
    while frame is not None:
        if frame.f_code.co_name == "_read":
            return True
        frame = frame.f_back
    return False

def hold(t):  # in the loop thread: the main thread's read waits on it meanwhile
    while not in_the_read():
        time.sleep(0.001)
    print("reading", flush=True)  # the Ctrl-C now lands in the read, not between two
    arrived.wait(30.0)
    return True

signal.signal(signal.SIGINT, ctrl_c)
threading.Thread(target=robot.wait_for, args=(hold,), kwargs={"timeout": 60.0}, daemon=True).start()
try:
    while True:
        robot.latest_odometry  # nearly all of the time is in this blocking read
except KeyboardInterrupt:
    print("interrupted", robot.commanded_velocity, flush=True)
    raise
"""


@pytest.mark.integration
async def test_ctrl_c_in_a_property_read_stops_the_robot_too() -> None:
    # The script holds its loop thread until its main thread is inside a read, so the
    # Ctrl-C is sent while the read waits (sent at random, it can land between two reads:
    # a KeyboardInterrupt in the script's own code, which no library sees).
    async with ChassisSimulator() as sim, script(READING, sim.port) as proc:
        assert await line(proc) == "reading"
        assert moving(sim)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        assert await line(proc) == "interrupted None"  # stopped before it was re-raised
        await until(lambda: any(is_zero(c) and t >= sent for t, c in drives(sim.firmware)))
        await until(lambda: still(sim), timeout=3.0)


@pytest.mark.integration
@pytest.mark.timing
async def test_ctrl_c_in_a_blocking_call_stops_the_robot_and_raises() -> None:
    async with ChassisSimulator() as sim, script(INTERRUPTED, sim.port) as proc:
        assert await line(proc) == "waiting"
        assert moving(sim)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        assert await line(proc) == "interrupted None"  # stopped before it was re-raised

        def zeros_since() -> list[float]:
            return [t for t, c in drives(sim.firmware) if is_zero(c) and t >= sent]

        await until(lambda: bool(zeros_since()), timeout=1.0)  # the pty in between
        zeros = zeros_since()
        print(f"Ctrl-C: zero {zeros[0] - sent:.3f} s after SIGINT")
        assert zeros[0] - sent < 0.3, zeros
        async with asyncio.timeout(10):
            _, err = await proc.communicate()
        assert "KeyboardInterrupt" in err.decode()
        assert proc.returncode != 0
        assert is_zero(drives(sim.firmware)[-1][1])
        await until(lambda: still(sim), timeout=3.0)


@pytest.mark.integration
@pytest.mark.timing
async def test_sigterm_stops_the_robot_and_exits_143() -> None:
    async with ChassisSimulator() as sim, script(DRIVING, sim.port) as proc:
        assert await line(proc) == "driving"
        await until(lambda: moving(sim))
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(10):
            await proc.wait()
        assert proc.returncode == 143
        # What the script wrote before it ended may still be in the pty: read it all.
        await until(lambda: is_zero(drives(sim.firmware)[-1][1]), timeout=1.0)
        frames = drives(sim.firmware)  # zero is the last velocity frame
        print(f"SIGTERM: zero {frames[-1][0] - sent:.3f} s after the signal")
        assert frames[-1][0] - sent < 1.0
        await until(lambda: still(sim), timeout=3.0)


@pytest.mark.integration
@pytest.mark.timing
async def test_sigkill_leaves_it_to_the_firmware_timeout() -> None:
    """Nothing can run after SIGKILL: no zero is written; the chassis firmware's own
    command timeout (0.5 s without a 0x02, modelled by the simulator) stops the wheels."""
    async with ChassisSimulator() as sim, script(DRIVING, sim.port) as proc:
        assert await line(proc) == "driving"
        await until(lambda: moving(sim))
        proc.send_signal(signal.SIGKILL)
        await proc.wait()
        killed = time.monotonic()
        took = await until(lambda: still(sim), timeout=5.0)
        last_time, last = drives(sim.firmware)[-1]
        assert not is_zero(last)  # honest: the process wrote no zero
        assert killed - last_time < 0.2
        print(f"SIGKILL: no zero; the firmware stopped the wheels {took:.3f} s after the kill")
        assert took <= 0.5 + 1.0, took  # the firmware's 0.5 s, then its braking ramp


@pytest.mark.integration
@pytest.mark.parametrize("how", ["exit", "exception"])
async def test_interpreter_exit_writes_zero(how: str) -> None:
    async with ChassisSimulator() as sim, script(EXITING, sim.port, how) as proc:
        assert await line(proc) == "moving"
        async with asyncio.timeout(10):
            _, err = await proc.communicate()
        assert proc.returncode == (0 if how == "exit" else 1), err.decode()
        assert ("the script failed" in err.decode()) == (how == "exception")
        # Written at exit, by atexit (it may still be in the pty when the process ends).
        await until(lambda: is_zero(drives(sim.firmware)[-1][1]), timeout=1.0)
        assert not is_zero(drives(sim.firmware)[0][1])
        await until(lambda: still(sim), timeout=3.0)
