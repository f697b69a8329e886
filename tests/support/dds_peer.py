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

Two peers: Fast DDS 2 (the system's, Debian 12's 2.9) and Fast DDS 3 (Debian 13's 3.1,
what ROS 2 Kilted and Lyrical run). The second is built inside a Debian 13 root that
``tools/system-deps.sh`` makes with debootstrap (`debian13_root`), in a user and mount
namespace of its own (no privilege needed once the root exists), and runs on that root's
own dynamic loader and libraries, so no chroot is needed to run it. `use_fast_dds` picks
the one `start_peer` starts by default.
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

__all__ = [
    "FAST_DDS",
    "SOURCES",
    "Event",
    "Peer",
    "build_peer",
    "debian13_root",
    "peer_cache_dir",
    "start_peer",
    "use_fast_dds",
]

#: The Fast DDS major versions a peer can be built with.
FAST_DDS = (2, 3)
#: The test ids of a test run against each (``[fastdds2]``, ``[fastdds3]``).
FAST_DDS_IDS = tuple(f"fastdds{major}" for major in FAST_DDS)

SOURCES = Path(__file__).resolve().parent.parent / "ros2_peer"
INSTALL_HINT = "install it with: sh tools/system-deps.sh"
IDL = "ros2_types.idl"
# Part of the cache key: a change in how the peer is built builds it again.
RECIPE = "fastddsgen -replace -t; g++ -std=c++17 -O1; -lfastrtps -lfastcdr -lpthread; v1"
RECIPE_3 = "debian13: fastddsgen 4; g++ -std=c++17 -O1; -lfastdds -lfastcdr -lpthread; v1"
#: Where tools/system-deps.sh makes the Debian 13 root (``CHASSIS_SDK_DEBIAN13`` elsewhere).
DEBIAN13 = "/var/cache/chassis-sdk/debian13"
#: Written last by tools/system-deps.sh: the root is complete.
DEBIAN13_DONE = ".chassis-sdk-complete"
INSTALL_HINT_3 = "make it with: sh tools/system-deps.sh (as root: debootstrap, about 1 GB)"
HEADER = Path("fastdds/dds/domain/DomainParticipantFactory.hpp")

Event = dict[str, Any]
"""One line of the peer's output: ``{"event": "matched", "t": 1712345678.9, ...}``."""


def _source_files() -> list[Path]:
    return [SOURCES / "peer.cpp", SOURCES / IDL]


def debian13_root() -> Path:
    """The Debian 13 root that holds Fast DDS 3 (``$CHASSIS_SDK_DEBIAN13``, else
    /var/cache/chassis-sdk/debian13)."""
    return Path(os.environ.get("CHASSIS_SDK_DEBIAN13") or DEBIAN13)


def _fast_dds_libraries(root: str = "") -> list[str]:
    """The Fast DDS libraries' real files (their versions are in their names)."""
    found = glob.glob(f"{root}/usr/lib/*/libfast*.so") + glob.glob(f"{root}/usr/*lib/libfast*.so")
    return sorted({os.path.realpath(p) for p in found})


def _digest(major: int = 2) -> str:
    # The sources, how they are built, and which Fast DDS they are built against (a new
    # libfastrtps soname after an upgrade builds the peer again).
    root = str(debian13_root()) if major == 3 else ""
    h = hashlib.sha256((RECIPE_3 if major == 3 else RECIPE).encode())
    h.update("\0".join(_fast_dds_libraries(root)).encode())
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


def _missing(major: int = 2) -> str | None:
    """Why the peer cannot be built here, in a few words, or ``None``."""
    if major == 3:
        root = debian13_root()
        if not (root / DEBIAN13_DONE).exists():
            return f"the Debian 13 root with Fast DDS 3 ({root}) is not there; {INSTALL_HINT_3}"
        if shutil.which("unshare") is None:
            return f"unshare (util-linux) is not installed; {INSTALL_HINT}"
        return None
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
_default_major = 2


def use_fast_dds(major: int) -> None:
    """Make `start_peer` start the Fast DDS ``major`` peer (2 or 3) by default."""
    global _default_major
    if major not in FAST_DDS:
        raise ValueError(f"Fast DDS {major}: the peers are {FAST_DDS}")
    _default_major = major


def build_peer(major: int = 2) -> Path:
    """The peer's binary for Fast DDS ``major``, built first if this content of the
    sources has not been.

    Raises:
        RuntimeError: fastddsgen, g++, the Fast DDS headers or the Debian 13 root are
            missing (with the install hint), or the build failed (with the compiler's
            last lines).
    """
    key = _digest(major)
    if key in _built:
        return _built[key]
    root = peer_cache_dir()
    binary = root / key / "peer"
    if not os.access(binary, os.X_OK):
        why = _missing(major)
        if why is not None:
            raise RuntimeError(f"DDS peer: {why}" + ("" if major == 3 else f"; {INSTALL_HINT}"))
        root.mkdir(parents=True, exist_ok=True)
        with _locked(root / f"{key}.lock"):
            if not os.access(binary, os.X_OK):  # another process may have built it meanwhile
                (_build_3 if major == 3 else _build)(root, key)
    _built[key] = binary
    return binary


def _loader(root: Path) -> list[str]:
    """The command prefix that runs one of ``root``'s programs on ``root``'s own dynamic
    loader and libraries (Debian 13's glibc and libstdc++ under this system's kernel)."""
    loaders = sorted(glob.glob(f"{root}/usr/lib*/ld-linux-*.so.*"))
    fast = glob.glob(f"{root}/usr/lib/*-linux-gnu/libfastdds.so.*")
    if not loaders or not fast:
        raise RuntimeError(f"DDS peer: no dynamic loader or libfastdds in {root}; {INSTALL_HINT_3}")
    return [loaders[0], "--library-path", os.path.dirname(fast[0])]


def _build_3(root: Path, key: str) -> None:
    """Build the Fast DDS 3 peer inside the Debian 13 root: the build directory bound
    onto its /build in a mount namespace of our own (a user namespace too when not
    root), fastddsgen 4 and g++ 14 run there."""
    debian = debian13_root()
    with _work_dir(root, key) as work:
        stem = IDL.removesuffix(".idl")
        java = sorted(glob.glob(f"{debian}/usr/lib/jvm/java-*-openjdk-*/lib"))
        # Java finds libjli through /proc, which the namespace has not: say where it is.
        java_lib = java[-1].removeprefix(str(debian)) if java else ""
        inside = (
            "cd /build && mkdir -p gen tmp"
            f" && LD_LIBRARY_PATH={java_lib} fastddsgen -replace -t tmp -d gen {IDL}"
            f" && g++ -std=c++17 -O1 -o peer -I gen peer.cpp gen/{stem}PubSubTypes.cxx"
            f" gen/{stem}TypeObjectSupport.cxx -lfastdds -lfastcdr -lpthread"
        )
        script = 'mount --bind "$1" "$2/build" && exec chroot "$2" /bin/sh -c "$3"'
        flags = ["--mount"] if os.geteuid() == 0 else ["--user", "--map-root-user", "--mount"]
        cmd = ["unshare", *flags, "sh", "-c", script, "sh", str(work), str(debian), inside]
        _run(cmd, work, "the Fast DDS 3 build in the Debian 13 root")
        if not (work / "peer").exists():
            raise RuntimeError(f"DDS peer: the Fast DDS 3 build wrote no peer in {work}")


@contextlib.contextmanager
def _work_dir(root: Path, key: str) -> Iterator[Path]:
    """A fresh directory holding the sources to build in: moved into place as
    ``root/key`` at once when the block ends without an error (a half-built peer is
    never seen), removed otherwise."""
    work = Path(tempfile.mkdtemp(prefix=f"{key[:12]}-", dir=root))
    try:
        for path in _source_files():
            shutil.copy2(path, work / path.name)
        yield work
        final = root / key
        if final.exists():
            shutil.rmtree(final)
        work.rename(final)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


def _build(root: Path, key: str) -> None:
    with _work_dir(root, key) as work:
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


async def start_peer(*args: str, binary: Path | None = None, fast_dds: int | None = None) -> Peer:
    """Start ``peer ARGS...`` (``build_peer(fast_dds)``'s binary unless ``binary``;
    ``fast_dds`` defaults to what `use_fast_dds` chose, else 2).

    Its output is read as it comes; use the result as an async context manager (or call
    ``stop()``) so that it never outlives the test.
    """
    needs("ros2", "starts the Fast DDS peer")
    major = _default_major if fast_dds is None else fast_dds
    exe = binary if binary is not None else await asyncio.to_thread(build_peer, major)
    prefix = _loader(debian13_root()) if major == 3 else []
    process = await asyncio.create_subprocess_exec(
        *prefix,
        str(exe),
        *args,
        stdin=asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        limit=1 << 22,  # a TFMessage line can be long
    )
    return Peer(process, args)
