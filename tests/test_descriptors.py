"""Descriptors: how many a chassis holds, and ports numbered past select()'s 1024.

pyserial's ``Serial.read`` calls ``select()``, which fails for any descriptor at or
above 1024; with pyserial's abort pipes each port held five or six descriptors, so a
process stopped hearing its robots at about 200 of them, and every failing read
callback logged a traceback, forever.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import importlib
import logging
import os
import resource
from collections.abc import Iterator
from typing import Any

import pytest

from chassis_sdk import Chassis
from chassis_sdk.core import transport
from chassis_sdk.sim import ChassisSimulator

pytestmark = pytest.mark.integration


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


async def test_a_chassis_holds_two_descriptors() -> None:
    async with ChassisSimulator() as sim:
        before = open_fds()
        async with Chassis(sim.port) as robot:
            async for _ in robot.telemetry():
                break
            held = open_fds() - before
        assert open_fds() == before
    # The port, and the link's own duplicate for writing; no pyserial abort pipes.
    assert held <= 2, held


@contextlib.contextmanager
def descriptors_past(number: int) -> Iterator[None]:
    """Fill the descriptor table so that the next ones opened are past ``number``."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = number + 256
    if hard != resource.RLIM_INFINITY and hard < want:
        pytest.skip(f"the hard descriptor limit ({hard}) is below {want}")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, want), hard))
    fillers = []
    try:
        null = os.open(os.devnull, os.O_RDONLY)
        fillers.append(null)
        while fillers[-1] < number:
            fillers.append(os.dup(null))
        yield
    finally:
        for fd in fillers:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


async def test_a_port_past_descriptor_1024_is_read(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.ERROR)
    with descriptors_past(1100):
        async with ChassisSimulator() as sim, Chassis(sim.port, request_timeout=0.5) as robot:
            link = robot._link.writer.link
            assert link is not None
            assert link.transport is not None
            fd = transport._serial_fd(link.transport.get_extra_info("serial"))
            assert fd is not None
            assert fd > 1024
            frames = 0
            async with asyncio.timeout(5):  # pyserial's read: never a frame, a traceback each
                async for _ in robot.telemetry():
                    frames += 1
                    if frames == 10:
                        break
            assert await robot.get_firmware_version() > 0
    assert not [r for r in caplog.records if "select" in r.getMessage()]


@pytest.mark.parametrize(
    "error",
    [OSError(errno.EIO, "Input/output error"), ValueError("filedescriptor out of range")],
    ids=["EIO", "ValueError"],
)
async def test_a_failing_read_is_a_lost_link_once_not_a_traceback_per_wakeup(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, error: Exception
) -> None:
    import types

    from chassis_sdk import ConnectionState

    # The link reads the port itself under every transport (after the first chunk,
    # which the transport's own read delivers), so the read to break is the link's.
    reader: Any = transport
    failures = 0

    def failing_read(fd: int, size: int) -> bytes:
        nonlocal failures
        failures += 1
        raise error

    broken = types.ModuleType("os")
    broken.__dict__.update(os.__dict__)
    broken.read = failing_read  # type: ignore[attr-defined]
    caplog.set_level(logging.ERROR)
    async with ChassisSimulator() as sim, Chassis(sim.port, reconnect=True) as robot:
        async for _ in robot.telemetry():
            break
        states = robot.connection_states()
        monkeypatch.setattr(reader, "os", broken)
        async with asyncio.timeout(5):
            async for state in states:
                if state is ConnectionState.RECONNECTING:
                    break
        monkeypatch.undo()
        await robot.wait_connected(timeout=5)
        async for _ in robot.telemetry():  # heard again after the reopen
            break
    assert failures == 1
    assert not [r for r in caplog.records if r.name == "asyncio"]


async def test_no_read_asks_for_more_than_read_size(monkeypatch: pytest.MonkeyPatch) -> None:
    """serialx asks for 256 KiB per read: past glibc's mmap threshold, so every read
    mapped, shrank and unmapped a buffer (three system calls and a page fault; 70 us
    per request round trip at p50 in benchmarks/latency.py)."""
    import types

    # The transport's own read delivers the first chunk, the link's every later one.
    readers: list[Any] = [transport]
    if transport.backend_name() == "serialx":
        readers.append(importlib.import_module("serialx.descriptor_transport"))
    sizes: list[int] = []

    def recording_read(fd: int, size: int) -> bytes:
        sizes.append(size)
        return os.read(fd, size)

    spy = types.ModuleType("os")
    spy.__dict__.update(os.__dict__)
    spy.read = recording_read  # type: ignore[attr-defined]
    for reader in readers:
        monkeypatch.setattr(reader, "os", spy)
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        async for _ in robot.telemetry():
            break
        await robot.get_firmware_version()
    assert sizes
    assert max(sizes) <= transport.READ_SIZE, max(sizes)


async def test_the_link_reads_the_port_itself_after_the_first_chunk(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every transport's read callback is Python of its own around one ``os.read``
    (serialx logs twice per read); the link registers its own reader on the port once
    the transport has delivered a chunk, and reads every later one itself."""
    import sys
    import types

    callers: list[str] = []
    real_read = os.read

    def recording_read(fd: int, size: int) -> bytes:
        callers.append(sys._getframe(1).f_code.co_qualname)
        return real_read(fd, size)

    spy = types.ModuleType("os")
    spy.__dict__.update(os.__dict__)
    spy.read = recording_read  # type: ignore[attr-defined]
    monkeypatch.setattr(transport, "os", spy)
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        frames = 0
        async for _ in robot.telemetry():
            frames += 1
            if frames == 10:
                break
        assert await robot.get_firmware_version() > 0
    # The pyserial transports' first read is their Serial.read (which the link
    # replaced with one os.read); serialx's is in its own module, not spied.
    if callers[0] != "Link._read_ready":
        assert callers.pop(0) == "_fd_reader.<locals>.read", callers[0]
    assert len(callers) >= 10
    assert set(callers) == {"Link._read_ready"}, set(callers)


async def test_the_rx_dump_follows_the_loggers_level_while_the_link_reads() -> None:
    # The link asks the logger nothing per read while DEBUG is off (it reads what the
    # logger has cached); a level set while it reads must still turn the dump on, and
    # off again, from the next read.
    log = logging.getLogger("chassis_sdk")
    dumps: list[str] = []

    class Dumps(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("rx "):
                dumps.append(record.getMessage())

    handler, old = Dumps(logging.DEBUG), log.level
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
            telemetry = robot.telemetry()
            for _ in range(5):
                await anext(telemetry)
            assert dumps == []
            log.setLevel(logging.DEBUG)
            async with asyncio.timeout(5):  # (frames read before the change may wait)
                while not dumps:
                    await anext(telemetry)
            assert all(bytes.fromhex(d[3:]) for d in dumps)
            log.setLevel(logging.INFO)
            await anext(telemetry)
            seen = len(dumps)
            for _ in range(5):
                await anext(telemetry)
            assert len(dumps) == seen
    finally:
        log.removeHandler(handler)
        log.setLevel(old)
