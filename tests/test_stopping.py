"""The robot stops on every path: a device that stops reading (or reads slowly when
``close()`` comes) never freezes the loop and gets zero as its last frame; ``close()``
fences off every writer; after the loop was blocked past the deadman the first frame out
is zero; a background task that fails writes zero first; SIGTERM and SIGHUP stop it.

From the field hardening of issue 11: every test here failed on the code before the fix
and runs on whichever pyserial transport is installed (CI runs it on each). Firmware is
played by the independent stand-ins of ``standin.py``, on ptys and TCP.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import select
import signal
import struct
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import chassis_sdk
from chassis_sdk import Chassis, ConnectionState, NotConnectedError
from chassis_sdk.core.transport import wait_lingering

from .support.helpers import TRANSPORTS, Heartbeat, ThreadedPeer, open_fds_on, until
from .support.stalls import drive_until_the_link_blocks
from .support.standin import (
    ChassisStandIn,
    Received,
    drive_frames,
    is_zero_drive,
    last_drive_is_zero,
)

pytestmark = pytest.mark.integration


def velocity(rec: Received) -> tuple[int, float]:
    """(vx mm/s, wz rad/s) of a mode-0 drive frame."""
    _, vx, wz = struct.unpack("<Hhf", rec.payload)
    return vx, wz


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


# --- a device that stops reading, or reads slowly when close() comes -----------------------------


@pytest.mark.timing
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
                # 0.1 is written at once, 0.3 (the newest) when the write period is over.
                await until(lambda: robot.written_velocity == (0.3, 0.0))
                if expired:  # the deadman runs out while the device is stuck
                    await until(lambda: robot.stats.command_expiries == 1)
                dev.resume_reading()
                await dev.wait_for(lambda fs: bool(drive_frames(fs)))
                first = drive_frames(dev.frames)[0]
                assert velocity(first) == ((0, 0.0) if expired else (300, 0.0))
                assert robot.stats.frames_discarded >= (2 if expired else 1)  # 0.2: never
        assert all(velocity(f)[0] in (0, 300) for f in drive_frames(dev.frames))


@pytest.mark.slow
@pytest.mark.timing
@pytest.mark.parametrize("tcp", TRANSPORTS)
@pytest.mark.parametrize("stall", [0.4, 2.5])  # within and well past CLOSE_TIMEOUT
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


@pytest.mark.timing
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


@pytest.mark.timing
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


# --- close() fences off every writer -------------------------------------------------------------


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


# --- after the loop was blocked past the deadman, the first frame out is zero --------------------


@pytest.mark.timing
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


# --- a failing background task writes zero before giving up --------------------------------------


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


# --- SIGTERM stops the robot like Ctrl-C ---------------------------------------------------------

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


@pytest.mark.parametrize("tcp", TRANSPORTS)
async def test_a_read_only_device_never_writes_not_even_the_zero_at_close(tcp: bool) -> None:
    """A viewer (``read_only=True``) writes no frame: commands and requests are refused
    before anything is written, and close() writes no zero."""
    from chassis_sdk import Board, ChassisError
    from chassis_sdk.sim import BoardSimulator, ChassisSimulator

    async with ChassisSimulator(tcp_port=0 if tcp else None) as sim:
        async with Chassis(sim.port, read_only=True) as robot:
            assert robot.read_only
            async for _ in robot.telemetry():
                break  # it reads
            for call in (
                lambda: robot.set_velocity(0.3, 0.0),
                robot.stop,
                robot.get_firmware_version,
                robot.emergency_stop,
            ):
                with pytest.raises(ChassisError, match="read-only"):
                    await call()
        assert len(sim.firmware.received) == 0
        assert robot.stats.frames_sent == 0
    async with BoardSimulator() as board_sim:
        async with Board(board_sim.port, read_only=True) as board:
            async for _ in board.imu():
                break
            with pytest.raises(ChassisError, match="read-only"):
                await board.set_led(True)
        assert len(board_sim.firmware.received) == 0
    with pytest.raises(TypeError, match="read_only"):
        Chassis("/dev/null", read_only=1)  # type: ignore[arg-type]
