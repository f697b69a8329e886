"""The real ``chassis-sdk`` in a subprocess, as an operator runs it: a command run to its
end (:func:`cli`), one running in the background and read line by line
(:func:`running`), the check that stderr is the one ``chassis-sdk: ...`` line of an
everyday failure (:func:`one_line`), and a port that never says anything
(:func:`silent_pty`)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import tty
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path

__all__ = ["CLI", "ROOT", "Running", "cli", "one_line", "running", "silent_pty"]

#: The repository: the commands run from here, so they import this checkout's package.
ROOT = Path(__file__).resolve().parents[2]
#: ``chassis-sdk`` as this interpreter runs it.
CLI = (sys.executable, "-m", "chassis_sdk.cli")


#: ``chassis-sdk`` with the modules it is given (argv[1], comma-separated) made missing,
#: as if their extra were not installed: importing one fails.
_WITHOUT = (
    "import runpy, sys\n"
    "for name in sys.argv.pop(1).split(','): sys.modules[name] = None\n"
    "runpy.run_module('chassis_sdk.cli', run_name='__main__', alter_sys=True)"
)


async def cli(
    *args: str,
    env: dict[str, str] | None = None,
    timeout: float = 30.0,
    cwd: Path = ROOT,
    without: tuple[str, ...] = (),
) -> tuple[int, str, str]:
    """Run ``chassis-sdk args`` to its end: ``(exit code, stdout, stderr)``. ``env`` is
    added to this process's environment; the modules ``without`` names cannot be
    imported in it (an extra not installed)."""
    command = (sys.executable, "-c", _WITHOUT, ",".join(without)) if without else CLI
    proc = await asyncio.create_subprocess_exec(
        *command, *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        cwd=cwd, env={**os.environ, **(env or {})},
    )  # fmt: skip
    async with asyncio.timeout(timeout):
        out, err = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


def one_line(err: str) -> str:
    """The whole of stderr is one ``chassis-sdk: ...`` line."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("chassis-sdk: "), err
    return lines[0]


@contextlib.contextmanager
def silent_pty() -> Iterator[str]:
    """A port that accepts bytes and never says anything."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


class Running:
    """A CLI command running in the background, read line by line."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.lines: list[str] = []

    async def wait_for_line(self, predicate: Callable[[str], bool], timeout: float = 10.0) -> str:
        assert self.proc.stdout is not None
        async with asyncio.timeout(timeout):
            while True:
                line = (await self.proc.stdout.readline()).decode()
                if not line:
                    raise AssertionError(f"ended before the line; got {self.lines}")
                self.lines.append(line)
                if predicate(line):
                    return line

    async def finish(self, timeout: float = 20.0) -> tuple[int, str, str]:
        async with asyncio.timeout(timeout):
            out, err = await self.proc.communicate()
        self.lines += out.decode().splitlines(keepends=True)
        assert self.proc.returncode is not None
        return self.proc.returncode, "".join(self.lines), err.decode()


@contextlib.asynccontextmanager
async def running(*args: str) -> AsyncIterator[Running]:
    """``chassis-sdk args`` running for the block; killed at its end if still running."""
    proc = await asyncio.create_subprocess_exec(
        *CLI, *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=ROOT
    )
    try:
        yield Running(proc)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
