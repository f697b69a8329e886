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


def _listens(pid: int, port: int) -> bool:
    """Whether process ``pid`` has a TCP socket listening on ``port`` (Linux /proc)."""
    inodes = set()
    with contextlib.suppress(OSError):
        for fd in os.listdir(f"/proc/{pid}/fd"):
            with contextlib.suppress(OSError):
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
                if target.startswith("socket:["):
                    inodes.add(target[8:-1])
    try:
        with open(f"/proc/{pid}/net/tcp") as table:
            lines = table.readlines()[1:]
    except OSError:  # it has exited
        return False
    for line in lines:
        fields = line.split()
        local, state, inode = fields[1], fields[3], fields[9]
        if state == "0A" and int(local.split(":")[1], 16) == port and inode in inodes:
            return True
    return False


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
        self._settings = (
            ("user root\n" if os.geteuid() == 0 else "")
            + "persistence false\nmax_queued_messages 10000\n"
            + ("set_tcp_nodelay true\n" if nodelay else "")
        )
        self._extra = extra or "allow_anonymous true\n"
        self._write_conf()
        self.proc: subprocess.Popen[bytes] | None = None
        self._started = False

    def _write_conf(self) -> None:
        self.conf.write_text(f"listener {self.port} 127.0.0.1\n{self._settings}{self._extra}")

    async def start(self) -> None:
        """Start it and wait until it listens.

        Ready means *this* mosquitto listens on the port, not that something accepts
        there: between :func:`free_port` and mosquitto's bind another process (another
        test's broker, under pytest-xdist) may take the port, and a test would then talk
        to that broker. On its first start it then moves to a new port; a restart keeps
        the port (clients reconnect to it) and fails if it cannot have it.
        """
        needs("mqtt", "starts mosquitto")
        for _ in range(1 if self._started else 5):
            self.proc = subprocess.Popen(  # noqa: ASYNC220 (a daemon: started, not waited on)
                [self.exe, "-c", str(self.conf)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            async with asyncio.timeout(10):
                while self.proc.poll() is None and not _listens(self.proc.pid, self.port):
                    await asyncio.sleep(0.02)
            if self.proc.poll() is None:
                self._started = True
                return
            if self._started:
                break
            self.port = free_port()
            self._write_conf()
        raise RuntimeError(f"mosquitto could not listen on 127.0.0.1:{self.port}")

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
