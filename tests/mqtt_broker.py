"""A real mosquitto on a loopback port, for the MQTT bridge's tests.

The tests need the broker (Debian's ``mosquitto`` package; ``.ci/run`` installs it):
without it they fail and say how to install it, rather than pass by skipping.
"""

from __future__ import annotations

import asyncio
import contextlib
import shutil
import socket
import subprocess
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path
from types import TracebackType

import pytest


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Broker:
    """``mosquitto`` on ``127.0.0.1:port``; :meth:`kill` and :meth:`start` again."""

    def __init__(self) -> None:
        exe = shutil.which("mosquitto") or (
            "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
        )
        if exe is None:
            pytest.fail("mosquitto is not installed (apt-get install -y mosquitto)")
        self.exe = exe
        self.port = _free_port()
        self._dir = tempfile.TemporaryDirectory(prefix="mosquitto-")
        self.conf = Path(self._dir.name) / "mosquitto.conf"
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
        )
        self.proc: subprocess.Popen[bytes] | None = None

    async def start(self) -> None:
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
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    async def __aenter__(self) -> Broker:
        await self.start()
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.kill()
        self._dir.cleanup()


@contextlib.asynccontextmanager
async def broker() -> AsyncIterator[Broker]:
    async with Broker() as b:
        yield b
