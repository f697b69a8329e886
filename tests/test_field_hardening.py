"""Field hardening (issue 11): the robot never keeps driving, a stuck device never
freezes the loop, a late reply never answers a later call, ports are exclusive,
connects are bounded, bad numbers are ``ValueError``, SIGTERM stops the robot.

Every test here failed on the code before the fix and runs on whichever pyserial
transport is installed; CI runs the file once on pyserial-asyncio and once on
pyserial-asyncio-fast. Firmware is played by the independent stand-ins of
``standin.py`` (frames packed by hand from the protocol notes), on ptys and TCP.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import select
import signal
import socket
import struct
import sys
import threading
import time
import tty
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

import chassis_sdk
from chassis_sdk import (
    Board,
    Chassis,
    ConnectionState,
    MotionLimits,
    NotConnectedError,
    PortOpenError,
    RequestTimeoutError,
)
from chassis_sdk.core.transport import wait_lingering
from chassis_sdk.sim import ChassisSimulator, ChassisSpec

from .stalls import NumberedReplies, drive_until_the_link_blocks, first_telemetry, own_answers
from .standin import (
    BoardStandIn,
    ChassisStandIn,
    Received,
    drive_frames,
    frame_a,
    frame_b,
    is_zero_drive,
    last_drive_is_zero,
)

TRANSPORTS = [pytest.param(False, id="pty"), pytest.param(True, id="tcp")]


def velocity(rec: Received) -> tuple[int, float]:
    """(vx mm/s, wz rad/s) of a mode-0 drive frame."""
    _, vx, wz = struct.unpack("<Hhf", rec.payload)
    return vx, wz


class Heartbeat:
    """Measures how long the event loop goes without running a 5 ms sleeper."""

    def __init__(self) -> None:
        self.max_gap = 0.0
        self._task: asyncio.Task[None] | None = None

    async def _beat(self) -> None:
        while True:
            t = time.monotonic()
            await asyncio.sleep(0.005)
            self.max_gap = max(self.max_gap, time.monotonic() - t)

    async def __aenter__(self) -> Heartbeat:
        self._task = asyncio.create_task(self._beat())
        await asyncio.sleep(0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task


async def until(condition: Callable[[], bool], timeout: float = 5.0) -> None:
    """Wait for a condition of the SDK's own state (its counters have no event)."""
    async with asyncio.timeout(timeout):
        while not condition():
            await asyncio.sleep(0.005)


def open_fds_on(path: str) -> int:
    """Descriptors this process holds on ``path``."""
    target = os.path.realpath(path)
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            n += os.readlink(f"/proc/self/fd/{fd}") == target
    return n


@contextlib.contextmanager
def unstick_after(dev: ChassisStandIn, seconds: float) -> Iterator[None]:
    """A safety net for the code before the fix, whose loop a stuck device froze: a
    thread reads the line after ``seconds`` if the test has not finished by then, so
    the test fails on its timing assertions instead of hanging."""
    done = threading.Event()
    master = dev._master

    def drain() -> None:
        if done.wait(seconds):
            return
        with contextlib.suppress(OSError):
            while select.select([master], [], [], 0.2)[0]:
                os.read(master, 65536)

    thread = threading.Thread(target=drain, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


# --- 1. a device that stops reading ------------------------------------------------------------


async def test_stuck_device_never_freezes_the_loop_and_close_sends_nothing_stale() -> None:
    async with ChassisStandIn(noise=False) as dev:
        robot = Chassis(dev.port, command_timeout=None)
        await robot.connect()
        dev.release_line()
        dev.stop_reading()
        dev.fill_line()
        with unstick_after(dev, 3.0):
            async with Heartbeat() as beat:
                await robot.set_velocity(0.3, 0.0)
                await robot.set_velocity(0.4, 0.0)
                await until(lambda: robot.stats.resends >= 3)
                t0 = time.monotonic()
                await robot.close()
                closing = time.monotonic() - t0
        assert beat.max_gap < 0.15, f"the loop froze for {beat.max_gap:.2f} s"
        assert closing < 1.5
        assert open_fds_on(dev.port) == 0, "close() left the port open"
        assert robot.stats.frames_discarded >= 4
        # The device reads again: nothing the host wrote while it was stuck arrives but
        # the final zero (kept when the rest was discarded).
        dev.resume_reading()
        await asyncio.wait_for(dev.eof.wait(), 3.0)
        assert [velocity(f) for f in drive_frames(dev.frames)] == [(0, 0.0)]


@pytest.mark.parametrize("expired", [False, True], ids=["newest", "expired-to-zero"])
async def test_stuck_device_gets_only_the_newest_velocity_when_it_reads_again(
    expired: bool,
) -> None:
    async with ChassisStandIn(noise=False) as dev:
        command_timeout = 0.2 if expired else None
        async with Chassis(dev.port, command_timeout=command_timeout) as robot:
            dev.stop_reading()
            dev.fill_line()
            with unstick_after(dev, 3.0):
                for v in (0.1, 0.2, 0.3):
                    await robot.set_velocity(v, 0.0)
                if expired:  # the deadman runs out while the device is stuck
                    await until(lambda: robot.stats.command_expiries == 1)
                dev.resume_reading()
                await dev.wait_for(lambda fs: bool(drive_frames(fs)))
                first = drive_frames(dev.frames)[0]
                assert velocity(first) == ((0, 0.0) if expired else (300, 0.0))
                assert robot.stats.frames_discarded >= 2
        assert all(velocity(f)[0] in (0, 300) for f in drive_frames(dev.frames))


@pytest.mark.parametrize("tcp", TRANSPORTS)
@pytest.mark.parametrize("stall", [0.4, 6.0])
async def test_a_device_slow_to_read_at_close_gets_the_zero_as_its_last_frame(
    tcp: bool, stall: float
) -> None:
    # Before: close() drained 0.25 s, then discarded and flushed everything, the zero
    # included, so the last frame the device ever got was 0.5 m/s.
    async with ChassisStandIn(noise=False, tcp=tcp, tcp_rcvbuf=4096) as dev:
        robot = Chassis(dev.port, close_linger=stall + 3.0)
        await robot.connect()
        dev.release_line()
        with unstick_after(dev, 30.0) if not tcp else contextlib.nullcontext():
            stalled = time.monotonic()
            control = await drive_until_the_link_blocks(dev, robot)
            t0 = time.monotonic()
            await robot.close()
            assert time.monotonic() - t0 < 1.0, "close() waited for the device"
            await control
            await asyncio.sleep(max(0.0, stall - (time.monotonic() - stalled)))
            dev.resume_reading()
            await asyncio.wait_for(dev.eof.wait(), 5.0)  # the host closed the line
        drives = drive_frames(dev.frames)
        assert drives, "the device got no drive frame at all"
        assert is_zero_drive(drives[-1]), f"the last frame was {velocity(drives[-1])}"
        assert open_fds_on(dev.port) == 0 if not tcp else dev.live_connections == 0


async def test_a_recording_does_not_cost_a_stalled_device_its_zero(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # The recording is closed when close() returns, while the zero may still wait for
    # the device: telemetry arriving then must not reach the closed file (before: an
    # error logged for every chunk read while the zero waited).
    async with ChassisStandIn(noise=False, tcp=True, tcp_rcvbuf=4096) as dev:
        robot = Chassis(dev.port, close_linger=5.0, record=tmp_path / "run.jsonl")
        await robot.connect()
        control = await drive_until_the_link_blocks(dev, robot)
        await robot.close()
        await control
        for _ in range(20):  # telemetry keeps coming while the zero waits
            dev.send(dev.telemetry_frame())
            await asyncio.sleep(0.005)
        dev.resume_reading()
        await asyncio.wait_for(dev.eof.wait(), 5.0)
        assert is_zero_drive(drive_frames(dev.frames)[-1])
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR] == []


async def test_past_close_linger_the_port_is_released_and_nothing_more_is_sent() -> None:
    # A socket's kernel buffer cannot be flushed: when the bound passes, the connection
    # is reset, so the kernel sends nothing more, the port is free to open again, and
    # nothing ever follows the zero (if it had left in time, it is still the last).
    async with ChassisStandIn(noise=False, tcp=True, tcp_rcvbuf=4096) as dev:
        robot = Chassis(dev.port, close_linger=0.3)
        await robot.connect()
        control = await drive_until_the_link_blocks(dev, robot)
        t0 = time.monotonic()
        await robot.close()
        await control
        await wait_lingering(timeout=2.0)  # the link gave up and closed
        assert time.monotonic() - t0 < 1.5
        dev.resume_reading()
        await asyncio.wait_for(dev.eof.wait(), 3.0)  # what its kernel held, then the reset
        drives = drive_frames(dev.frames)
        zeros = [i for i, f in enumerate(drives) if is_zero_drive(f)]
        assert zeros in ([], [len(drives) - 1]), "a frame came after the zero"


async def test_run_waits_for_the_final_zero_of_a_device_slow_to_read() -> None:
    # Under chassis_sdk.run the program ends only once a lingering zero has left (or
    # its bound passed): here the device reads again 0.5 s after main() returned.
    dev = ChassisStandIn(noise=False, tcp=True, tcp_rcvbuf=4096)
    timings: dict[str, float] = {}

    async def main() -> None:
        await dev.__aenter__()
        robot = Chassis(dev.port, close_linger=5.0)
        await robot.connect()
        control = await drive_until_the_link_blocks(dev, robot)
        await robot.close()
        await control
        asyncio.get_running_loop().call_later(0.5, dev.resume_reading)
        timings["main returned"] = time.monotonic()

    def scenario() -> None:
        chassis_sdk.run(main(), uvloop=False)
        timings["run returned"] = time.monotonic()

    await asyncio.to_thread(scenario)
    drives = drive_frames(dev.frames)
    assert drives
    assert is_zero_drive(drives[-1])
    assert 0.4 < timings["run returned"] - timings["main returned"] < 3.0


# --- 2. close() fences off every writer --------------------------------------------------------


@pytest.mark.parametrize("tcp", TRANSPORTS)
@pytest.mark.parametrize("how", ["close", "async-with"])
async def test_zero_is_the_last_velocity_frame_when_close_races_a_control_task(
    tcp: bool, how: str
) -> None:
    trials, failures = 15, []
    for trial in range(trials):
        async with ChassisStandIn(noise=False, tcp=tcp, telemetry_period=0.005) as dev:
            raced: list[BaseException] = []
            enough = 3 + trial % 4

            async def control(robot: Chassis, raced: list[BaseException] = raced) -> None:
                # As fast as the loop lets it: every await in close() is a chance.
                try:
                    while True:
                        await robot.set_velocity(0.3, 0.0)
                        await asyncio.sleep(0)
                except NotConnectedError as exc:
                    raced.append(exc)

            robot = Chassis(dev.port)
            if how == "close":
                await robot.connect()
                dev.release_line()
                task = asyncio.create_task(control(robot))
                await dev.wait_for(lambda fs, n=enough: len(drive_frames(fs)) >= n)
                await robot.close()
            else:
                async with robot:
                    dev.release_line()
                    task = asyncio.create_task(control(robot))
                    await dev.wait_for(lambda fs, n=enough: len(drive_frames(fs)) >= n)
            await asyncio.wait_for(task, 1.0)
            await asyncio.wait_for(dev.eof.wait(), 3.0)
            frames = drive_frames(dev.frames)
            if not is_zero_drive(frames[-1]):
                failures.append(trial)
            assert raced, "the control task must end with NotConnectedError"
    assert failures == [], f"non-zero last frame in trials {failures} of {trials}"


async def test_calls_racing_close_get_not_connected_error() -> None:
    async with ChassisStandIn(noise=False) as dev:
        robot = Chassis(dev.port)
        await robot.connect()
        closing = asyncio.create_task(robot.close())
        await asyncio.sleep(0)  # close() has started
        for call in (
            robot.set_velocity(0.2, 0.0),
            robot.stop(),
            robot.get_firmware_version(),
            robot.emergency_stop(),
        ):
            with pytest.raises(NotConnectedError):
                await call
        await closing


# --- 3. a late reply never answers a later call ------------------------------------------------


async def test_a_late_reply_does_not_answer_the_next_call() -> None:
    async with (
        NumberedReplies(noise=False, delays=[0.35, 0.3]) as dev,
        Chassis(dev.port, request_timeout=0.2, retries=0) as robot,
    ):
        with pytest.raises(RequestTimeoutError):
            await robot.get_firmware_version()
        robot.request_timeout = 1.0
        # The first reply arrives while this call waits: it is not this call's.
        assert await robot.get_firmware_version() == 2
        assert robot.stats.late_replies == 1
        assert robot.stats.unmatched_replies == 0


async def test_a_device_slower_than_the_timeout_never_returns_stale_data() -> None:
    async with (
        NumberedReplies(noise=False, delays=[0.3] * 10) as dev,
        Chassis(dev.port, request_timeout=0.2, retries=0) as robot,
    ):
        for _ in range(3):
            with pytest.raises(RequestTimeoutError):
                await robot.get_firmware_version()
        await until(lambda: robot.stats.late_replies == 3)
        assert robot.stats.unmatched_replies == 0


@pytest.mark.parametrize("tcp", TRANSPORTS)
@pytest.mark.parametrize("factor", [1.1, 1.5, 3.0])
async def test_on_a_slow_device_every_reply_answers_its_own_call(tcp: bool, factor: float) -> None:
    # Every reply comes `factor` request timeouts after its request, numbered by the
    # request it answers: a call may only ever return one of its own attempts' numbers.
    # Before the latency-following quarantine, at 1.5x a call got the reply to the
    # previous call's second attempt (the quarantine, one request_timeout, ran out first).
    timeout = 0.15
    async with (
        NumberedReplies(noise=False, tcp=tcp, latency=factor * timeout) as dev,
        Chassis(dev.port, request_timeout=timeout, retries=2) as robot,
    ):
        answers = await own_answers(dev, robot, 4)
        assert all(a is None or a in own for own, a in answers), answers
        if factor < 2.5:  # (at 3x a reply comes just as its call's last attempt times out)
            assert sum(a is not None for _, a in answers) >= 2, answers  # it does answer
        assert robot.stats.unmatched_replies == 0


async def test_a_reply_to_an_earlier_attempt_answers_the_same_call() -> None:
    async with (
        NumberedReplies(noise=False, delays=[0.3, 0.25]) as dev,
        Chassis(dev.port, request_timeout=0.2, retries=2) as robot,
    ):
        # Attempt 1 at 0 s (answered at 0.3 s), attempt 2 at 0.2 s (answered at 0.45):
        # the first reply to come answers the call; the other is late.
        assert await robot.get_firmware_version() == 1
        assert await robot.get_firmware_version() == 3  # after the late one went by
        assert robot.stats.late_replies == 1


@dataclass
class _VeryLateBoard(BoardStandIn):
    """Holds the reply to the first LED request (claiming the LED is on) and sends it
    just before answering the 257th: after 256 allocations the old round-robin gave
    that request the same id."""

    _stale: bytes = b""

    def on_frame(self, rec: Received) -> None:
        if rec.kind == 0x01:
            n = len(self.of_kind(0x01))
            if n == 1:
                self._stale = frame_b(b"\xfe\xce", 0x01, bytes((rec.payload[1], 1)))
                return
            if n == 257:
                self.send(self._stale)
        super().on_frame(rec)


async def test_a_very_late_board_reply_does_not_answer_a_request_with_a_reused_id() -> None:
    async with (
        _VeryLateBoard(noise=False) as dev,
        Board(dev.port, request_timeout=0.1, retries=0) as board,
    ):
        with pytest.raises(RequestTimeoutError):
            await board.get_led()
        board.request_timeout = 1.0
        for _ in range(256):
            assert await board.get_led() is False
        assert board.stats.late_replies == 1
        ids = [f.payload[1] for f in dev.of_kind(0x01)]
        assert ids[0] not in ids[1:]  # retired for the quarantine


# --- 4. connects are bounded and never block the loop -------------------------------------------


@contextlib.contextmanager
def black_hole(port: int = 0) -> Iterator[int]:
    """A listener whose accept queue is full: SYNs go unanswered, connects hang."""
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", port))
    srv.listen(0)
    port = srv.getsockname()[1]
    fill = []
    for _ in range(3):
        c = socket.socket()
        c.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            c.connect(("127.0.0.1", port))
        fill.append(c)
    try:
        yield port
    finally:
        for c in fill:
            c.close()
        srv.close()


async def test_connect_to_a_host_that_never_answers_is_bounded_and_does_not_block() -> None:
    with black_hole() as port:
        async with Heartbeat() as beat:
            robot = Chassis(f"socket://127.0.0.1:{port}", connect_timeout=0.5)
            t0 = time.monotonic()
            with pytest.raises(PortOpenError, match="no answer within 0.5 s"):
                await robot.connect()
            took = time.monotonic() - t0
    assert 0.4 < took < 1.5
    assert beat.max_gap < 0.15, f"the loop was blocked for {beat.max_gap:.2f} s"
    assert robot.connection_state is ConnectionState.DISCONNECTED


async def test_reconnect_attempts_never_stall_another_robot() -> None:
    async with (
        ChassisStandIn(noise=False, tcp=True) as lost,
        ChassisStandIn(noise=False) as other_dev,
        Chassis(lost.port, reconnect=True, connect_timeout=0.3) as robot,
        Chassis(other_dev.port, command_timeout=None) as other,
    ):
        port = int(lost.port.rsplit(":", 1)[1])
        await other.set_velocity(0.2, 0.0)
        lost.unplug()
        with black_hole(port):
            await until(lambda: robot.connection_state is ConnectionState.RECONNECTING)
            start = time.monotonic()
            n0 = len(drive_frames(other_dev.frames))
            await other_dev.wait_for(lambda fs: len(drive_frames(fs)) >= n0 + 30, timeout=5.0)
            assert robot.connection_state is ConnectionState.RECONNECTING
        times = [f.time for f in drive_frames(other_dev.frames) if f.time >= start]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert max(gaps) < 0.2, f"the other robot's resends stalled for {max(gaps):.2f} s"


# --- 5. close() during a reconnect leaves nothing open ------------------------------------------


async def test_close_during_a_reconnect_leaves_no_connection(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from chassis_sdk.core.transport import open_link as real_open_link

    attempt = asyncio.Event()

    async def open_link(*args: Any, **kwargs: Any) -> Any:
        attempt.set()  # a (re)connect attempt starts now
        return await real_open_link(*args, **kwargs)

    monkeypatch.setattr("chassis_sdk.core.supervisor.open_link", open_link)
    leaked = []
    for trial in range(36):
        async with ChassisStandIn(noise=False, tcp=True) as dev:
            robot = Chassis(dev.port, reconnect=True)
            await robot.connect()
            await dev.wait_for(lambda fs: dev.live_connections == 1)
            attempt.clear()
            dev.unplug()
            await dev.replug()
            # Close 0 to 11 loop iterations into the reconnect attempt: across the
            # whole window in which the SDK opens and completes the connection.
            await attempt.wait()
            for _ in range(trial % 12):
                await asyncio.sleep(0)
            await robot.close()
            try:
                await dev.wait_for(lambda fs: dev.live_connections == 0, timeout=2.0)
            except TimeoutError:
                leaked.append(trial)
    assert leaked == [], f"connections left open after close() in trials {leaked}"


@pytest.mark.parametrize("tcp", TRANSPORTS)
async def test_close_during_connect_returns_only_once_nothing_is_open(tcp: bool) -> None:
    async with ChassisStandIn(noise=False, tcp=tcp) as dev:
        robot = Chassis(dev.port)
        connecting = asyncio.create_task(robot.connect())
        await asyncio.sleep(0)  # connect() is opening the port
        await robot.close()
        if tcp:
            await dev.wait_for(lambda fs: dev.live_connections == 0, timeout=2.0)
        else:
            assert open_fds_on(dev.port) == 1  # the stand-in's own, not the SDK's
        with pytest.raises(NotConnectedError, match="closed while connecting"):
            await connecting
        assert robot.connection_state is ConnectionState.DISCONNECTED
        await robot.connect()  # and it opens normally afterwards
        await robot.close()


# --- 6. exclusive ports --------------------------------------------------------------------------


async def test_the_first_telemetry_after_opening_is_fresh_however_long_nobody_read() -> None:
    # A simulator (1 kHz telemetry) runs with nobody reading until its line is full and
    # it drops bytes, as a device left powered with no host does. Before: the first
    # telemetry() loop got seconds-old frames (64 KiB the simulator held, behind what the
    # kernel held), thousands within milliseconds; now the port's input is flushed on
    # open and a device holds no more than a UART's worth, so the first frame is fresh.
    age, _ = await first_telemetry()
    assert age < 0.1, f"the first telemetry was made {age:.3f} s before it arrived"


async def test_a_second_open_of_a_serial_port_fails_at_once_naming_the_holder() -> None:
    async with ChassisStandIn() as dev, Chassis(dev.port) as robot:
        second = Chassis(dev.port)
        with pytest.raises(
            PortOpenError, match=rf"port busy, held by this process \(pid {os.getpid()}\)"
        ):
            await second.connect()
        # Another process is told which process holds the port.
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "chassis_sdk.cli", "info", dev.port,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        _, err = await asyncio.wait_for(proc.communicate(), 30)
        assert proc.returncode == 1
        assert f"port busy, held by process {os.getpid()}" in err.decode()
        assert robot.is_connected
        assert robot.stats.frames > 0


# --- 7. bad numbers are ValueError, always ----------------------------------------------------

BAD = [
    pytest.param(float("nan"), id="nan"),
    pytest.param(float("inf"), id="inf"),
    pytest.param(-float("inf"), id="-inf"),
    pytest.param(1e308, id="1e308"),
    pytest.param(-1e308, id="-1e308"),
    pytest.param(10**400, id="10**400"),
    pytest.param(1e30, id="1e30"),
    pytest.param(True, id="bool"),
    pytest.param("1", id="str"),
    pytest.param(None, id="None"),
]

#: (name, call, what a valid value of the argument may also be): a large positive
#: number is a valid time or factor, ``None`` a valid "not given".
_CHASSIS_CALLS: list[tuple[str, Callable[[Chassis, Any], Awaitable[Any]], str]] = [
    ("set_velocity linear", lambda r, x: r.set_velocity(x, 0.0), ""),
    ("set_velocity angular", lambda r, x: r.set_velocity(0.0, x), ""),
    ("set_velocity duration", lambda r, x: r.set_velocity(0.1, 0.0, duration=x), "large none"),
    ("set_wheel_speeds left", lambda r, x: r.set_wheel_speeds(x, 0.0), ""),
    ("set_wheel_speeds right", lambda r, x: r.set_wheel_speeds(0.0, x), ""),
    ("set_wheel_speeds duration", lambda r, x: r.set_wheel_speeds(0, 0, duration=x), "large none"),
    ("wait_for timeout", lambda r, x: r.wait_for(lambda t: True, x), "large"),
    (
        "configure_odometry slip",
        lambda r, x: r.configure_odometry("wheels", slip_factor=x, track_width=0.5),
        "large",
    ),
    (
        "configure_odometry track",
        lambda r, x: r.configure_odometry("wheels", track_width=x),
        "large none",
    ),
    ("configure_odometry gap", lambda r, x: r.configure_odometry(max_gap=x), "large"),
]
_BOARD_CALLS: list[tuple[str, Callable[[Board, Any], Awaitable[Any]], str]] = [
    ("set_velocity linear", lambda b, x: b.set_velocity(x, 0.0), ""),
    ("set_velocity angular", lambda b, x: b.set_velocity(0.0, x), ""),
    ("set_velocity duration", lambda b, x: b.set_velocity(0.1, 0.0, duration=x), "large none"),
    ("set_motor_pwm pwm", lambda b, x: b.set_motor_pwm(1, x), ""),
    ("set_motor_pwm motor", lambda b, x: b.set_motor_pwm(x, 10), ""),
    ("set_servo angle", lambda b, x: b.set_servo(1, x), ""),
    ("set_servo servo", lambda b, x: b.set_servo(x, 10.0), ""),
    ("configure_odometry gap", lambda b, x: b.configure_odometry(max_gap=x), "large"),
]
_MAKERS: list[tuple[str, Callable[[Any], object], str]] = [
    ("request_timeout", lambda x: Chassis("/dev/null", request_timeout=x), "large"),
    ("connect_timeout", lambda x: Chassis("/dev/null", connect_timeout=x), "large"),
    ("MotionLimits", lambda x: MotionLimits(max_linear=x), "large none"),
    ("reset_odometry", lambda x: Chassis("/dev/null").reset_odometry(x, 0.0), "large negative"),
]


def _valid_anyway(bad: Any, allows: str) -> bool:
    if bad is None:
        return "none" in allows
    if bad in (1e30, 1e308):
        return "large" in allows
    return bad == -1e308 and "negative" in allows


@pytest.mark.parametrize("bad", BAD)
async def test_every_bad_number_is_a_value_error_before_a_byte_is_written(bad: Any) -> None:
    async with (
        ChassisStandIn(noise=False) as cdev,
        BoardStandIn(noise=False) as bdev,
        Chassis(cdev.port) as robot,
        Board(bdev.port) as board,
    ):
        calls: list[tuple[Any, str, Callable[[Any, Any], Awaitable[Any]], str]] = [
            *((robot, *c) for c in _CHASSIS_CALLS),
            *((board, *c) for c in _BOARD_CALLS),
        ]
        for device, name, call, allows in calls:
            if _valid_anyway(bad, allows):
                continue
            sent = device.stats.frames_sent
            with pytest.raises(ValueError, match=r"must be|out of range|unknown"):
                await call(device, bad)
            assert device.stats.frames_sent == sent, name
        # Nothing was written for any of them (the stand-ins heard no command at all).
        assert drive_frames(cdev.frames) == []
        assert bdev.frames == []
    for _name, make, allows in _MAKERS:
        if not _valid_anyway(bad, allows):
            with pytest.raises(ValueError, match="must be"):
                make(bad)


# --- 8. a device object works in any event loop it is connected in --------------------------


class ThreadedPeer:
    """A protocol A firmware stand-in on its own thread: it times what arrives on the
    wire while the test's event loop is blocked or replaced, and streams telemetry."""

    def __init__(self) -> None:
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self._slave = slave
        self.port = os.ttyname(slave)
        self.chunks: list[tuple[float, bytes]] = []
        self._arrived = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        seq = 0
        next_telemetry = time.monotonic()
        while not self._stop.is_set():
            ready = select.select([self._master], [], [], 0.005)[0]
            if ready:
                with contextlib.suppress(OSError), self._arrived:
                    self.chunks.append((time.monotonic(), os.read(self._master, 4096)))
                    self._arrived.notify_all()
            if time.monotonic() >= next_telemetry:
                payload = struct.pack("<HHHhhhhhh", 246, 0, 4, 0, 0, 0, 0, 0, 0)
                with contextlib.suppress(OSError):
                    os.write(self._master, frame_a(0x81, payload, seq))
                seq = (seq + 1) & 0xFFFF
                next_telemetry += 0.02

    def drive_frames(self) -> list[Received]:
        out: list[Received] = []
        buf = bytearray()
        parser = ChassisStandIn()
        for t, data in list(self.chunks):
            buf += data
            out += [r for r in parser.parse(buf, t) if r.kind == 0x02]
        return out

    def wait_for(self, predicate: Callable[[list[Received]], bool], timeout: float = 3.0) -> None:
        """Block until ``predicate(drive frames)`` holds (woken by each chunk read)."""
        with self._arrived:
            assert self._arrived.wait_for(lambda: predicate(self.drive_frames()), timeout)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        os.close(self._master)
        os.close(self._slave)


def test_a_device_works_in_a_second_event_loop() -> None:
    peer = ThreadedPeer()
    robot = Chassis(peer.port, command_timeout=0.2)
    try:

        async def session() -> None:
            async with robot:
                await robot.set_velocity(0.2, 0.0)
                resends = robot.stats.resends
                expiries = robot.stats.command_expiries
                await until(lambda: robot.stats.resends >= resends + 3)
                await until(lambda: robot.stats.command_expiries > expiries)
                assert robot.connection_state is ConnectionState.CONNECTED
                assert await robot.wait_for(lambda t: True, 1.0)

        asyncio.run(session())
        first = len(peer.drive_frames())
        asyncio.run(session())  # a new loop: the same object must work in it
        # The close's zero is the last frame (it may still be on its way).
        peer.wait_for(lambda frames: len(frames) > first + 3 and is_zero_drive(frames[-1]))
        frames = peer.drive_frames()
        assert sum(not is_zero_drive(f) for f in frames[first:]) >= 3  # resends in loop 2
    finally:
        peer.close()


async def test_a_failing_background_task_writes_zero_before_giving_up() -> None:
    async with ChassisStandIn(noise=False) as dev:
        robot = Chassis(dev.port, command_timeout=None)
        trigger = asyncio.Event()

        async def broken_monitor(timeout: float) -> None:
            await trigger.wait()
            raise RuntimeError("a bug in a background task")

        robot._link._monitor_link = broken_monitor  # type: ignore[method-assign]
        async with robot:
            await robot.set_velocity(0.3, 0.0)
            await dev.wait_for(lambda fs: len(drive_frames(fs)) >= 3)
            trigger.set()
            await dev.wait_for(last_drive_is_zero)
            await until(lambda: robot.connection_state is ConnectionState.LOST)
            with pytest.raises(NotConnectedError):
                await robot.set_velocity(0.3, 0.0)
        assert is_zero_drive(drive_frames(dev.frames)[-1])


# --- 9. after the loop was blocked past the deadman, the first frame out is zero --------------


def test_after_a_blocked_loop_the_first_velocity_frame_out_is_zero() -> None:
    peer = ThreadedPeer()
    try:

        async def session() -> float:
            async with Chassis(peer.port, command_timeout=0.3) as robot:
                await robot.set_velocity(0.3, 0.0)
                blocked_at = time.monotonic()
                time.sleep(0.8)  # application code blocks the loop past the deadman
                await until(lambda: robot.stats.command_expiries == 1)
            return blocked_at

        blocked_at = asyncio.run(session())
        peer.wait_for(lambda frames: any(f.time > blocked_at + 0.05 for f in frames))
        after = [f for f in peer.drive_frames() if f.time > blocked_at + 0.05]
        assert after, "nothing arrived after the block"
        assert is_zero_drive(after[0]), f"a stale frame left after the block: {velocity(after[0])}"
    finally:
        peer.close()


# --- 10. SIGTERM stops the robot like Ctrl-C ---------------------------------------------------

_DRIVER = """
import asyncio, sys
import chassis_sdk

async def main() -> None:
    async with chassis_sdk.Chassis(sys.argv[1], command_timeout=None) as robot:
        await robot.set_velocity(0.3, 0.0)
        print("driving", flush=True)
        await asyncio.Event().wait()

chassis_sdk.run(main())
"""


@pytest.mark.parametrize(
    ("sig", "program"),
    [
        pytest.param(signal.SIGTERM, "script", id="SIGTERM-run"),
        pytest.param(signal.SIGHUP, "script", id="SIGHUP-run"),
        pytest.param(signal.SIGTERM, "cli", id="SIGTERM-cli-drive"),
    ],
)
async def test_sigterm_and_sighup_write_zero_before_the_process_exits(
    sig: signal.Signals, program: str
) -> None:
    async with ChassisStandIn(noise=False) as dev:
        if program == "script":
            args = ["-c", _DRIVER, dev.port]
        else:
            args = [
                "-m",
                "chassis_sdk.cli",
                "drive",
                dev.port,
                "--linear",
                "0.3",
                "--duration",
                "60",
            ]
        proc = await asyncio.create_subprocess_exec(
            sys.executable, *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
        )
        await dev.wait_for(lambda fs: len(drive_frames(fs)) >= 3, timeout=30)
        assert not is_zero_drive(drive_frames(dev.frames)[-1])
        proc.send_signal(sig)
        _, err = await asyncio.wait_for(proc.communicate(), 10)
        assert proc.returncode == 128 + sig, err.decode()
        await dev.wait_for(last_drive_is_zero, timeout=2)


_SWALLOWER = """
import asyncio, sys
import chassis_sdk

async def main() -> None:
    async with chassis_sdk.Chassis(sys.argv[1], command_timeout=None) as robot:
        await robot.set_velocity(0.3, 0.0)
        print("driving", flush=True)
        try:
            await asyncio.Event().wait()
        except asyncio.CancelledError:
            pass  # lost, as asyncio.wait_for loses one before Python 3.12 (gh-86296)
        await asyncio.Event().wait()

chassis_sdk.run(main())
"""


async def test_sigterm_stops_the_robot_even_when_a_library_loses_the_cancellation() -> None:
    """A first cancellation swallowed inside the program (aiomqtt's publish does, through
    asyncio.wait_for, about one SIGTERM in three) must not keep the robot driving."""
    async with ChassisStandIn(noise=False) as dev:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", _SWALLOWER, dev.port,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        await dev.wait_for(lambda fs: len(drive_frames(fs)) >= 3, timeout=30)
        proc.send_signal(signal.SIGTERM)
        _, err = await asyncio.wait_for(proc.communicate(), 10)
        assert proc.returncode == 128 + signal.SIGTERM, err.decode()
        await dev.wait_for(last_drive_is_zero, timeout=2)


# --- 11. break unsubscribes at once --------------------------------------------------------------


async def test_leaving_a_loop_unsubscribes_even_while_the_subscription_is_held() -> None:
    async with (
        ChassisStandIn(noise=False, telemetry_period=0.005) as dev,
        Chassis(dev.port, queue_size=4) as robot,
    ):
        subs = []

        async def returns_from_the_loop() -> None:
            sub = robot.telemetry()
            subs.append(sub)
            async for _ in sub:
                return

        async def raises_in_the_loop() -> None:
            sub = robot.telemetry()
            subs.append(sub)
            async for _ in sub:
                raise KeyError("boom")

        held = robot.telemetry()
        async for _ in held:
            break
        assert len(robot._telemetry) == 0
        await returns_from_the_loop()
        assert len(robot._telemetry) == 0
        with pytest.raises(KeyError):
            await raises_in_the_loop()
        assert len(robot._telemetry) == 0
        # The held subscriptions buffer nothing and drop nothing from now on.
        await until(lambda: dev.seq > 40)
        assert robot.stats.queue_drops == 0
        async for _ in held:  # a loop left is a subscription ended
            raise AssertionError("a closed subscription yielded")


# --- 12. sequence gaps under either numbering ---------------------------------------------------


@pytest.mark.parametrize("per_id", [False, True], ids=["shared-counter", "per-id-counters"])
async def test_sequence_gaps_are_right_under_either_numbering(per_id: bool) -> None:
    async with (
        ChassisStandIn(noise=False, per_id_seq=per_id) as dev,
        Chassis(dev.port) as robot,
    ):
        for _ in range(30):  # replies interleave with telemetry
            await robot.get_firmware_version()
            await robot.get_hardware_version()
        assert robot.stats.sequence_gaps == 0, "false gaps"
        assert robot.sequence_scheme == ("per-id" if per_id else "shared")
        async with robot.telemetry() as frames:  # the device's telemetry is seen
            for _ in range(3):
                await anext(frames)
        dev.seq += 5  # a real break
        await until(lambda: robot.stats.sequence_gaps == 1)
        for _ in range(5):
            await robot.get_firmware_version()
        assert robot.stats.sequence_gaps == 1


@pytest.mark.parametrize("scheme", ["shared", "per-id"])
async def test_the_simulator_numbers_frames_either_way(scheme: Any) -> None:
    async with (
        ChassisSimulator(ChassisSpec(sequence=scheme)) as sim,
        Chassis(sim.port) as robot,
    ):
        await robot.enable_power_telemetry(True)
        async with robot.power() as power:
            for _ in range(10):
                await anext(power)
                await robot.get_firmware_version()
        assert robot.sequence_scheme == scheme
        assert robot.stats.sequence_gaps == 0
