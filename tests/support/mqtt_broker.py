"""A real mosquitto on a loopback port, for the MQTT bridge's tests and benchmark.

The tests need the broker (Debian's ``mosquitto`` package; ``.ci/run`` installs it):
without it they fail and say how to install it, rather than pass by skipping. Nothing
here imports pytest at import time, so ``benchmarks/mqtt_fleet.py`` uses it too.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path

from .watch import needs

__all__ = ["Broker", "Mosquitto", "broker", "find_mosquitto"]


def find_mosquitto() -> str | None:
    """The broker's path, or ``None`` (Debian installs it in /usr/sbin)."""
    found = shutil.which("mosquitto")
    if found is None and Path("/usr/sbin/mosquitto").exists():
        found = "/usr/sbin/mosquitto"
    return found


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Mosquitto:
    """``mosquitto`` on ``127.0.0.1:port``, anonymous, without persistence.

    Args:
        extra: Configuration lines after the listener's (default: anonymous access).
        nodelay: ``set_tcp_nodelay true``, as docs/mqtt.md recommends: without it the
            broker's Nagle algorithm holds a small message (an e-stop) up to 40 ms
            behind a busy stream to the same client (the delayed ACK).

    Raises:
        RuntimeError: mosquitto is not installed.
    """

    def __init__(self, extra: str = "", *, nodelay: bool = True) -> None:
        exe = find_mosquitto()
        if exe is None:
            raise RuntimeError("mosquitto is not installed (apt-get install -y mosquitto)")
        self.exe = exe
        self.port = free_port()
        self._dir = tempfile.TemporaryDirectory(prefix="mosquitto-")
        self.conf = Path(self._dir.name) / "mosquitto.conf"
        self.dir = Path(self._dir.name)
        # Settings after the listener line are that listener's (TLS files, ...).
        # As root, mosquitto drops to the user "mosquitto", who cannot read a test's
        # files (key, passwords) in a private temporary directory: stay root there.
        user = "user root\n" if os.geteuid() == 0 else ""
        self.conf.write_text(
            f"{user}listener {self.port} 127.0.0.1\npersistence false\n"
            "max_queued_messages 10000\n"
            + ("set_tcp_nodelay true\n" if nodelay else "")
            + (extra or "allow_anonymous true\n")
        )
        self.proc: subprocess.Popen[bytes] | None = None

    async def start(self) -> None:
        """Start it and wait until it accepts connections."""
        needs("mqtt", "starts mosquitto")
        self.proc = subprocess.Popen(  # noqa: ASYNC220 (a daemon: started, not waited on)
            [self.exe, "-c", str(self.conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        async with asyncio.timeout(10):
            while True:
                with contextlib.suppress(OSError):
                    _, writer = await asyncio.open_connection("127.0.0.1", self.port)
                    writer.close()
                    return
                await asyncio.sleep(0.02)

    def kill(self) -> None:
        """Kill it (a broker that vanishes)."""
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    def cleanup(self) -> None:
        self.kill()
        self._dir.cleanup()


class Broker(Mosquitto):
    """:class:`Mosquitto`, failing the test (not skipping it) when it is missing."""

    def __init__(self, extra: str = "", *, nodelay: bool = True) -> None:
        if find_mosquitto() is None:
            import pytest

            pytest.fail("mosquitto is not installed (apt-get install -y mosquitto)")
        super().__init__(extra, nodelay=nodelay)


@contextlib.asynccontextmanager
async def broker(extra: str = "", *, nodelay: bool = True) -> AsyncIterator[Broker]:
    b = Broker(extra, nodelay=nodelay)
    await b.start()
    try:
        yield b
    finally:
        b.cleanup()
