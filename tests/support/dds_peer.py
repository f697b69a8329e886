"""An independent DDS peer for the ROS 2 bridge's tests: eProsima Fast DDS (the middleware
behind ROS 2's default RMW), where the bridge runs on Cyclone DDS.

``build_peer()`` compiles ``tests/ros2_peer/peer.cpp`` (its command line is documented at
the top of that file) against fastddsgen's code for ``tests/ros2_peer/ros2_types.idl``,
once per content of those sources: the binary is cached under
``$XDG_CACHE_HOME/chassis_sdk/dds-peer/<sha256>/peer`` (``~/.cache`` without it).
``start_peer()`` runs it as an asyncio subprocess and collects its JSON lines::

    async with await start_peer("sub", "twist", "rt/cmd_vel", "--count", "3") as sub:
        await sub.wait_for("matched", timeout=10)
        sample = await sub.wait_for(lambda e: e["event"] == "sample")

Needs Debian's ``fastddsgen``, ``libfastrtps-dev`` and ``g++`` (``sh tools/system-deps.sh``
installs them): without them ``build_peer()`` raises, so a test that needs the peer fails
and says how to install it, rather than pass by skipping. Nothing here imports pytest.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import glob
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any

from .watch import needs

__all__ = ["SOURCES", "Event", "Peer", "build_peer", "peer_cache_dir", "start_peer"]

SOURCES = Path(__file__).resolve().parent.parent / "ros2_peer"
INSTALL_HINT = "install it with: sh tools/system-deps.sh"
IDL = "ros2_types.idl"
# Part of the cache key: a change in how the peer is built builds it again.
RECIPE = "fastddsgen -replace -t; g++ -std=c++17 -O1; -lfastrtps -lfastcdr -lpthread; v1"
HEADER = Path("fastdds/dds/domain/DomainParticipantFactory.hpp")

Event = dict[str, Any]
"""One line of the peer's output: ``{"event": "matched", "t": 1712345678.9, ...}``."""


def _source_files() -> list[Path]:
    return [SOURCES / "peer.cpp", SOURCES / IDL]


def _fast_dds_libraries() -> list[str]:
    """The Fast DDS libraries' real files (their versions are in their names)."""
    found = glob.glob("/usr/lib/*/libfast*.so") + glob.glob("/usr/*lib/libfast*.so")
    return sorted({os.path.realpath(p) for p in found})


def _digest() -> str:
    # The sources, how they are built, and which Fast DDS they are built against (a new
    # libfastrtps soname after an upgrade builds the peer again).
    h = hashlib.sha256(RECIPE.encode())
    h.update("\0".join(_fast_dds_libraries()).encode())
    for path in _source_files():
        data = path.read_bytes()
        h.update(f"\0{path.name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def peer_cache_dir() -> Path:
    """Where built peers are kept: ``$XDG_CACHE_HOME`` (else ``~/.cache``)/chassis_sdk/dds-peer."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "chassis_sdk" / "dds-peer"


def _find_header() -> Path | None:
    dirs = [d for d in os.environ.get("CPATH", "").split(":") if d]
    dirs += ["/usr/include", "/usr/local/include"]
    for d in dirs:
        if (Path(d) / HEADER).exists():
            return Path(d) / HEADER
    return None


def _missing() -> str | None:
    """Why the peer cannot be built here, in a few words, or ``None``."""
    if shutil.which("fastddsgen") is None:
        return "fastddsgen (Debian's fastddsgen) is not installed"
    if shutil.which("g++") is None:
        return "g++ is not installed"
    if _find_header() is None:
        return f"the Fast DDS headers ({HEADER}, Debian's libfastrtps-dev) are not installed"
    return None


def _run(cmd: list[str], cwd: Path, what: str) -> None:
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=600, check=False)
    if done.returncode != 0:
        text = re.sub(r"\x1b\[[0-9;]*m", "", done.stdout + done.stderr)  # fastddsgen's colours
        out = text.strip().splitlines()
        tail = " | ".join(out[-8:])
        raise RuntimeError(f"DDS peer: {what} failed ({done.returncode}): {tail}")


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    with path.open("a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


_built: dict[str, Path] = {}


def build_peer() -> Path:
    """The peer's binary, built first if this content of the sources has not been.

    Raises:
        RuntimeError: fastddsgen, g++ or the Fast DDS headers are missing (with the
            install hint), or the build failed (with the compiler's last lines).
    """
    key = _digest()
    if key in _built:
        return _built[key]
    root = peer_cache_dir()
    binary = root / key / "peer"
    if not os.access(binary, os.X_OK):
        why = _missing()
        if why is not None:
            raise RuntimeError(f"DDS peer: {why}; {INSTALL_HINT}")
        root.mkdir(parents=True, exist_ok=True)
        with _locked(root / f"{key}.lock"):
            if not os.access(binary, os.X_OK):  # another process may have built it meanwhile
                _build(root, key)
    _built[key] = binary
    return binary


def _build(root: Path, key: str) -> None:
    work = Path(tempfile.mkdtemp(prefix=f"{key[:12]}-", dir=root))
    try:
        for path in _source_files():
            shutil.copy2(path, work / path.name)
        gen = work / "gen"
        gen.mkdir()
        # -t: its preprocessed copy goes here, not to a fixed name in /tmp (another user's
        # file there, or another build at the same time, would break this one).
        tmp = work / "tmp"
        tmp.mkdir()
        _run(["fastddsgen", "-replace", "-t", str(tmp), "-d", "gen", IDL], work, "fastddsgen")
        stem = IDL.removesuffix(".idl")
        cmd = [
            "g++", "-std=c++17", "-O1", "-o", "peer", "-I", "gen",
            "peer.cpp", f"gen/{stem}.cxx", f"gen/{stem}PubSubTypes.cxx",
            "-lfastrtps", "-lfastcdr", "-lpthread",
        ]  # fmt: skip
        if not (gen / f"{stem}PubSubTypes.cxx").exists():
            raise RuntimeError(f"DDS peer: fastddsgen wrote no {stem}PubSubTypes.cxx in {gen}")
        _run(cmd, work, "g++")
        # Move the finished build into place at once: a half-built one is never seen.
        final = root / key
        if final.exists():
            shutil.rmtree(final)
        work.rename(final)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


def _named(name: str) -> Callable[[Event], bool]:
    def test(e: Event) -> bool:
        return e.get("event") == name

    return test


class Peer:
    """A running peer: its events as they come, and ways to wait for them.

    An async context manager: leaving the block stops the peer (SIGTERM, then SIGKILL
    after ``grace`` seconds) if it is still running.

    Attributes:
        args: The peer's arguments (after the binary).
        events: Every line it printed, parsed, in order; a line that is not JSON is kept as
            ``{"event": "unparsed", "line": ...}``.
        stderr: The lines it wrote on stderr.
    """

    def __init__(self, process: asyncio.subprocess.Process, args: tuple[str, ...]) -> None:
        self.process = process
        self.args = args
        self.events: list[Event] = []
        self.stderr: list[str] = []
        self.grace = 3.0
        self._changed = asyncio.Condition()
        self._eof = False
        self._tasks = [
            asyncio.create_task(self._read_stdout()),
            asyncio.create_task(self._read_stderr()),
        ]

    async def _read_stdout(self) -> None:
        assert self.process.stdout is not None
        try:
            async for raw in self.process.stdout:
                line = raw.decode(errors="replace").rstrip("\n")
                if not line:
                    continue
                try:
                    parsed = json.loads(line)
                except ValueError:
                    parsed = None
                event: Event = (
                    parsed if isinstance(parsed, dict) else {"event": "unparsed", "line": line}
                )
                async with self._changed:
                    self.events.append(event)
                    self._changed.notify_all()
        finally:
            async with self._changed:
                self._eof = True
                self._changed.notify_all()

    async def _read_stderr(self) -> None:
        assert self.process.stderr is not None
        async for raw in self.process.stderr:
            self.stderr.append(raw.decode(errors="replace").rstrip("\n"))

    @property
    def returncode(self) -> int | None:
        return self.process.returncode

    def named(self, name: str) -> list[Event]:
        """The events called ``name`` so far (``"sample"``, ``"matched"``, ...)."""
        return [e for e in self.events if e.get("event") == name]

    @property
    def samples(self) -> list[Event]:
        """The samples received so far (a ``sub``)."""
        return self.named("sample")

    def _describe(self, lines: int = 12) -> str:
        shown = [json.dumps(e) for e in self.events[-lines:]] + self.stderr[-lines:]
        return f"peer {' '.join(self.args)}: last lines:\n  " + "\n  ".join(shown or ["(none)"])

    async def wait_for(
        self,
        predicate: str | Callable[[Event], bool],
        timeout: float = 10.0,
        *,
        since: int = 0,
    ) -> Event:
        """The first event (from index ``since`` of ``events``) that matches.

        Args:
            predicate: An event's name, or a test of an event.
            timeout: Seconds to wait.
            since: Look at ``events[since:]`` only (``len(peer.events)``: only new ones).

        Raises:
            TimeoutError: None came in ``timeout``, or the peer ended without one; the
                message holds the peer's last lines.
        """
        test: Callable[[Event], bool]
        if isinstance(predicate, str):
            test = _named(predicate)
            what = repr(predicate)
        else:
            test = predicate
            what = getattr(predicate, "__name__", "an event")
        index = since
        try:
            async with asyncio.timeout(timeout), self._changed:
                while True:
                    while index < len(self.events):
                        event = self.events[index]
                        index += 1
                        if test(event):
                            return event
                    if self._eof:
                        break
                    await self._changed.wait()
        except TimeoutError:
            raise TimeoutError(f"no {what} in {timeout} s; {self._describe()}") from None
        await self.process.wait()
        raise TimeoutError(
            f"no {what}: the peer exited ({self.process.returncode}); {self._describe()}"
        )

    async def wait(self, timeout: float = 30.0) -> int:
        """Wait for the peer to exit by itself; its exit code (all its output read).

        Raises:
            TimeoutError: Still running after ``timeout`` s (it is left running).
        """
        try:
            async with asyncio.timeout(timeout):
                code = await self.process.wait()
                await asyncio.gather(*self._tasks)
        except TimeoutError:
            raise TimeoutError(f"still running after {timeout} s; {self._describe()}") from None
        return code

    async def stop(self) -> int:
        """Stop it (SIGTERM: it deletes its entities first; SIGKILL after ``grace`` s)."""
        if self.process.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                self.process.send_signal(signal.SIGTERM)
            try:
                async with asyncio.timeout(self.grace):
                    await self.process.wait()
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    self.process.kill()
                await self.process.wait()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        code = self.process.returncode
        assert code is not None
        return code

    async def __aenter__(self) -> Peer:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.stop()


async def start_peer(*args: str, binary: Path | None = None) -> Peer:
    """Start ``peer ARGS...`` (``build_peer()``'s binary unless ``binary``).

    Its output is read as it comes; use the result as an async context manager (or call
    ``stop()``) so that it never outlives the test.
    """
    needs("ros2", "starts the Fast DDS peer")
    exe = binary if binary is not None else await asyncio.to_thread(build_peer)
    process = await asyncio.create_subprocess_exec(
        str(exe),
        *args,
        stdin=asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        limit=1 << 22,  # a TFMessage line can be long
    )
    return Peer(process, args)
