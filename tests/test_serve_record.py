"""``chassis-sdk serve --record``: the live session is recorded by the one MCAP recorder
(:class:`chassis_sdk.recording.McapRecording`), so a hard kill loses at most its flush
interval, as an application's ``record=`` does.

The command runs in a subprocess from a neutral directory, so ``PYTHONPATH`` chooses
the package it runs (``PYTHONPATH=/tmp/before`` runs an older tree against this test).
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import time
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.records import Channel, Header, Message
from mcap.stream_reader import StreamReader

from chassis_sdk.recording.mcap import FLUSH_INTERVAL
from chassis_sdk.sim import ChassisSimulator

pytestmark = [pytest.mark.surface, pytest.mark.integration, pytest.mark.timeout(60)]

#: What a hard kill may lose beyond the flush interval: the time between two messages
#: (the flush comes with a message), the kill's own latency, a loaded test machine.
MARGIN = 0.5
#: How long the server records before the kill (several flushes).
RECORD_FOR = 3.0


def read_mcap(path: Path) -> tuple[bool, list[tuple[str, int]], str | None]:
    """Read an MCAP file as a reader does after a hard kill, up to where it stops:
    (whether it starts with a header, ``(topic, log_time)`` of every message in file
    order, and why the reading stopped early: ``None`` if it did not)."""
    header = False
    topics: dict[int, str] = {}
    found: list[tuple[str, int]] = []
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, record_size_limit=1 << 30).records:
                if isinstance(record, Header):
                    header = True
                elif isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message):
                    found.append((topics[record.channel_id], record.log_time))
        except McapError as exc:  # a file cut off by the kill: read up to there
            return header, found, f"{type(exc).__name__}: {exc}"
    return header, found, None


async def wait_for_telemetry(path: Path, proc: asyncio.subprocess.Process, err: Path) -> None:
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        if proc.returncode is not None:
            pytest.fail(f"serve ended ({proc.returncode}): {err.read_text()}")
        if path.exists() and path.stat().st_size > 0:
            _, found, _ = read_mcap(path)
            if any(topic == "/chassis/telemetry" for topic, _ in found):
                return
        await asyncio.sleep(0.1)
    size = path.stat().st_size if path.exists() else None
    pytest.fail(f"no telemetry in {path.name} within 20 s (size {size}): {err.read_text()}")


@pytest.mark.timing
async def test_a_hard_kill_of_serve_loses_at_most_the_flush_interval(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    err = tmp_path / "serve.err"
    async with ChassisSimulator() as sim:
        with err.open("wb") as stderr:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "chassis_sdk.cli", "serve", sim.port,
                "--foxglove-port", "0", "--record", str(path),
                stdout=asyncio.subprocess.DEVNULL, stderr=stderr, cwd=tmp_path,
                env=dict(os.environ),
            )  # fmt: skip
        try:
            await wait_for_telemetry(path, proc, err)
            await asyncio.sleep(RECORD_FOR)
            killed_at = time.time()
            proc.send_signal(signal.SIGKILL)
            await proc.wait()
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
    assert proc.returncode == -signal.SIGKILL
    header, found, stopped = read_mcap(path)
    assert header, "the file does not start with an MCAP header"
    topics = {topic for topic, _ in found}
    assert {"/chassis/telemetry", "/chassis/raw/rx"} <= topics, (topics, stopped)
    last = max(log_time for _, log_time in found) / 1e9
    lost = killed_at - last
    print(f"lost {lost:.3f} s at the kill ({len(found)} messages; stopped: {stopped})")
    assert lost <= FLUSH_INTERVAL + MARGIN, (
        f"the last message was {lost:.2f} s before the kill (flush interval {FLUSH_INTERVAL} s)"
    )
