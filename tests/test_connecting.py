"""Opening, reconnecting and closing during either: connects are bounded and never
block the loop (nor another robot's watchdog), ``close()`` during a connect or a
reconnect leaves nothing open, the first telemetry after opening is fresh, and ports are
exclusive, the refusal naming who holds the port in words that say what it is.

From the field hardening of issue 11, against the stand-ins of ``standin.py``, on ptys
and TCP.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import socket
import sys
import time
import tty
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from chassis_sdk import Chassis, ConnectionState, NotConnectedError, PortOpenError
from chassis_sdk.core.ports import command_line, lock_holder
from chassis_sdk.sim import ChassisSimulator

from .support.helpers import TRANSPORTS, Heartbeat, open_fds_on, until
from .support.stalls import first_telemetry
from .support.standin import ChassisStandIn, drive_frames

# --- connects are bounded and never block the loop -----------------------------------------------


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


@pytest.mark.integration
@pytest.mark.timing
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


@pytest.mark.integration
@pytest.mark.timing
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


# --- close() during a connect or a reconnect leaves nothing open ---------------------------------


@pytest.mark.integration
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


@pytest.mark.integration
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


# --- the first telemetry after opening is fresh --------------------------------------------------


@pytest.mark.integration
@pytest.mark.timing
async def test_the_first_telemetry_after_opening_is_fresh_however_long_nobody_read() -> None:
    # A simulator (1 kHz telemetry) runs with nobody reading until its line is full and
    # it drops bytes, as a device left powered with no host does. Before: the first
    # telemetry() loop got seconds-old frames (64 KiB the simulator held, behind what the
    # kernel held), thousands within milliseconds; now the port's input is flushed on
    # open and a device holds no more than a UART's worth, so the first frame is fresh.
    age, _ = await first_telemetry()
    assert age < 0.1, f"the first telemetry was made {age:.3f} s before it arrived"


# --- exclusive ports -----------------------------------------------------------------------------


@pytest.mark.integration
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


#: The installed ``chassis-sdk`` script, as an operator runs it.
SCRIPT = Path(sys.executable).with_name("chassis-sdk")


@pytest.mark.parametrize(
    ("argv", "shown"),
    [
        (
            ["/srv/venv/bin/python3", "/srv/venv/bin/chassis-sdk", "monitor", "/dev/x"],
            "chassis-sdk monitor /dev/x",
        ),
        (
            ["/usr/bin/python3.11", "-u", "-m", "chassis_sdk.cli", "record", "p"],
            "chassis_sdk.cli record p",
        ),
        (["/usr/bin/minicom", "-D", "/dev/ttyUSB0"], "minicom -D /dev/ttyUSB0"),
        ([], ""),
    ],
)
def test_command_line_keeps_the_program_and_its_arguments(argv: list[str], shown: str) -> None:
    assert command_line(argv) == shown


def test_a_long_command_line_is_cut_and_marked() -> None:
    shown = command_line(["tool", *["argument"] * 20])
    assert len(shown) == 80
    assert shown.startswith("tool argument")
    assert shown.endswith("…")


@pytest.mark.integration
@pytest.mark.skipif(not SCRIPT.exists(), reason="needs the installed chassis-sdk script")
async def test_info_on_a_port_monitor_holds_names_monitor_and_its_subcommand() -> None:
    async with ChassisSimulator() as sim:
        port = sim.port
        monitor = await asyncio.create_subprocess_exec(
            str(SCRIPT), "monitor", sim.port, "--json", stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
        )  # fmt: skip
        try:
            await until(lambda: lock_holder(sim.port) is not None, timeout=15)
            info = await asyncio.create_subprocess_exec(
                str(SCRIPT), "info", sim.port, stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            async with asyncio.timeout(30):
                _, err = await info.communicate()
        finally:
            monitor.terminate()
            await monitor.wait()
    lines = err.decode().strip().splitlines()
    assert info.returncode != 0
    assert len(lines) == 1, lines
    assert f"held by process {monitor.pid} (chassis-sdk monitor {port} --json)" in lines[0]
    assert os.sep + "python" not in lines[0]


# --- the flush at open ----------------------------------------------------------------------


@pytest.mark.integration
async def test_a_frame_between_the_flush_and_a_queued_read_is_not_a_hang_up() -> None:
    # Opening flushes what the port received before; a frame that lands between that
    # flush and the transport's read callback already queued for it must not read as an
    # unplugged device (a usb: open awaits a thread in between: CI saw it once).
    from chassis_sdk.core.transport import Link, open_link
    from chassis_sdk.protocol import (
        ChassisDecoder,
        ChassisEncoder,
        ChassisStatus,
        DockingState,
        Telemetry,
        WheelSpeeds,
    )

    loop = asyncio.get_running_loop()
    master, slave = os.openpty()
    tty.setraw(slave)
    got: list[Any] = []
    lost: list[Exception | None] = []

    def factory() -> Link[Any]:
        return Link(
            ChassisDecoder(), lambda m, now: got.extend(m), lost.append, logging.getLogger("t")
        )

    link = await open_link(os.ttyname(slave), 115200, factory)
    try:
        frame = ChassisEncoder().encode(
            Telemetry(
                24.6, ChassisStatus(0), DockingState.SEARCHING, 0.0, 0.0, WheelSpeeds(0, 0, 0, 0)
            )
        )

        def frame_then_flush() -> None:
            # The loop is held here while the frame lands in the port; the flush is
            # queued ahead of the read callback the next poll queues for that frame.
            os.write(master, frame)
            time.sleep(0.05)
            loop.call_soon(link.flush_input)

        loop.call_soon(frame_then_flush)
        await asyncio.sleep(0.1)
        assert lost == []  # before: "device disconnected" (serialx) / "no data" (pyserial)
        assert link.transport is not None
        os.write(master, frame)  # and it still reads
        async with asyncio.timeout(2):
            while not got:
                await asyncio.sleep(0.01)
    finally:
        if link.transport is not None:
            link.transport.close()
        await asyncio.sleep(0.05)
        os.close(master)
        os.close(slave)
