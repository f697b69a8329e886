"""The ROS 2 bridge against an independent DDS stack, as a robot's user feels it: how
soon teleop moves the robot and how soon it stops, how odometry reaches Nav2, how long
discovery takes, and what the bridge costs (about a minute; --quick: 30 s).

    pip install -e ".[ros2]" --group bench; sh tools/system-deps.sh   # the Fast DDS peer's build
    python benchmarks/ros2.py [--quick] [--json FILE]

The bridge (``Ros2Bridge``, Cyclone DDS) bridges a ``ChassisSimulator`` on a pty; the
other side is eProsima Fast DDS 2.9, the middleware of ROS 2's default RMW
(``tests/support/dds_peer.py``), playing teleop (a ``cmd_vel`` writer) and Nav2 (an
``odom`` reader) over RTPS on UDP. Times on both sides are the wall clock of one
machine; the simulator's receive times (``time.monotonic()``) are converted to it.

1. **first command -> motion**: the peer's first ``published`` -> the simulator reading
   the first velocity frame of that value. Floor: ``robot.set_velocity()`` called in
   process -> the simulator reading it; the difference is the DDS hop and the bridge.
   Beside it, the sample the robot moved on (the newest published before the frame) ->
   the frame (the peer prints ``published`` once ``write()`` returned, and Fast DDS
   sends within it: figures near zero can be a little negative). Teleop starts writing
   once *its* writer has matched the bridge's reader;
   when the bridge's reader has not yet matched that writer, the first sample (volatile)
   is not delivered and the robot moves on the second, one period (50 ms) later.
2. **last command -> stopped**, the writer alive and silent (``--hold``): the last
   ``published`` -> the simulator's zero frame, and -> the first telemetry that measures
   zero. Floor: the deadman (``command_timeout`` 0.5 s), and the same deadman given in
   process (``set_velocity(duration=0.5)``).
3. **writer gone -> zero** (``command_timeout=5``, so that only the leaving can stop the
   robot this soon): the peer's ``deleting_writer`` (printed just before it deletes its
   writer) -> the simulator's zero frame. Floor:
   ``robot.stop()`` in process -> the zero frame.
4. **odometry**: the rate a Fast DDS reader of ``odom`` receives over a few seconds,
   beside the device's telemetry rate counted in process over the same window; and the
   stamp-to-receipt latency (the peer's receive time - ``header.stamp``, the reading's
   wall clock), beside the floor: the reading -> an in-process ``async for`` over
   ``robot.odometry()``.
5. **discovery**: a peer spawned -> its ``matched`` (and its ``started``, once its
   participant and endpoint exist, -> ``matched``), a fresh bridge (and Cyclone) per
   configuration, peers one after another: multicast (the default); unicast only, with
   multicast off in the namespace and the peer ``--unicast``: ``Discovery(range=
   "LOCALHOST")`` (``ParticipantIndex auto``), Cyclone's own configuration
   (``CYCLONEDDS_URI``: ``AllowMulticast false`` and a ``Peer``, no ``ParticipantIndex``:
   Cyclone 11 then picks ``auto`` itself, its ``default`` without multicast), and
   ``ParticipantIndex none`` (Cyclone's older default: arbitrary unicast ports, which a
   unicast-only peer cannot find; one try, counted as missed). Beside them, the
   multicast discovery of every peer of 1-4.
6. **cost at 50 Hz**: a simulator and a ``Chassis`` for a window with a peer subscribed
   to ``odom``, in a fresh process without the bridge (the floor) and one with it:
   process CPU time per second (every thread, Cyclone's included; 100 % = one core), the
   RSS after warm-up and its growth over the window; the bridge's share is the
   difference, also per odometry message published (``odom`` and ``/tf``).

DDS runs only in a network namespace of its own whose only interface is loopback: the
script runs itself again under ``unshare -n`` (``-rn`` when not root), sets ``lo`` up
with multicast and a route for 224.0.0.0/4, and refuses to run when it cannot.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from all import machine  # this directory's all.py

from chassis_sdk import Chassis
from chassis_sdk.devices.chassis.messages import DriveVelocity
from chassis_sdk.sim import ChassisSimulator
from tests.support.dds_peer import Peer, build_peer, start_peer
from tests.support.ros2 import bridged, drives

if TYPE_CHECKING:
    pass

T = TypeVar("T")
SELF = str(Path(__file__).resolve())
ZERO = DriveVelocity(0, 0.0)

#: Set in the namespace's processes: the inode of the host's network namespace.
NETNS = "CHASSIS_SDK_BENCH_NETNS"
SBIN = os.pathsep.join(["/usr/sbin", "/sbin", "/usr/bin", "/bin"])
DEADMAN = 0.5
#: Cyclone's own unicast discovery: no multicast, one peer, no ParticipantIndex.
CYCLONE_UNICAST = (
    '<CycloneDDS><Domain Id="any"><General><AllowMulticast>false</AllowMulticast></General>'
    '<Discovery>{index}<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain>'
    "</CycloneDDS>"
)
DISCOVERIES = {
    "multicast": "multicast (SPDP), a fresh bridge",
    "localhost": 'unicast: Discovery(range="LOCALHOST")',
    "cyclone": "unicast: Cyclone's own, no ParticipantIndex",
    "index-none": "unicast: ParticipantIndex none",
}


# --- the namespace ----------------------------------------------------------------------------


def _netns_inode() -> int:
    return os.stat("/proc/self/ns/net").st_ino


def _tool(name: str) -> str:
    found = shutil.which(name) or shutil.which(name, path=SBIN)
    if found is None:
        raise RuntimeError(f"{name} is not installed")
    return found


def _refuse(why: str) -> int:
    print(f"ros2.py: not run: {why} (DDS runs only in a network namespace of its own)",
          file=sys.stderr)  # fmt: skip
    return 1


def reexec() -> int:
    """Run this script again in a new network namespace; its exit code."""
    try:
        unshare = _tool("unshare")
        build_peer()  # here, so that a missing compiler says so before anything runs
    except RuntimeError as exc:
        return _refuse(str(exc))
    flags = ["-n"] if os.geteuid() == 0 else ["-rn"]
    probe = subprocess.run([unshare, *flags, "true"], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        why = (probe.stderr.strip().splitlines() or ["unshare failed"])[-1]
        return _refuse(f"cannot make a network namespace ({why})")
    env = dict(os.environ, **{NETNS: str(_netns_inode())})
    cmd = [unshare, *flags, "--", sys.executable, SELF, *sys.argv[1:]]
    return subprocess.run(cmd, env=env, check=False).returncode


def in_own_namespace() -> bool:
    host = os.environ.get(NETNS)
    return host is not None and host != str(_netns_inode())


def ip(*args: str) -> None:
    done = subprocess.run([_tool("ip"), *args], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {(done.stderr or done.stdout).strip()}")


def setup_namespace() -> None:
    ip("link", "set", "lo", "up")
    ip("link", "set", "lo", "multicast", "on")
    ip("route", "add", "224.0.0.0/4", "dev", "lo")
    out = subprocess.run([_tool("ip"), "-o", "link", "show"], capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    names = {line.split(":")[1].strip().split("@")[0] for line in out.splitlines() if ":" in line}
    if names != {"lo"}:
        raise RuntimeError(f"interfaces other than lo: {sorted(names)}")


def multicast_off() -> None:
    ip("route", "del", "224.0.0.0/4", "dev", "lo")
    ip("link", "set", "lo", "multicast", "off")


# --- helpers --------------------------------------------------------------------------------


def to_wall(monotonic: float) -> float:
    return monotonic + (time.time() - time.monotonic())


def to_monotonic(wall: float) -> float:
    return wall - (time.time() - time.monotonic())


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def summary(values: list[float], scale: float = 1.0) -> dict[str, float]:
    """n, median, p99 and max of ``values`` (times ``scale``); NaN when there are none."""
    if not values:
        return {"n": 0, "median": math.nan, "p99": math.nan, "max": math.nan}
    scaled = [v * scale for v in values]
    return {
        "n": len(scaled),
        "median": statistics.median(scaled),
        "p99": percentile(scaled, 0.99),
        "max": max(scaled),
    }


async def poll(get: Callable[[], T | None], timeout: float, what: str) -> T:
    """``get()``'s first value that is not ``None``, polled every millisecond (the
    simulator's log of frames and the telemetry log have nothing to wait on)."""
    try:
        async with asyncio.timeout(timeout):
            while (value := get()) is None:  # noqa: ASYNC110 (polling a log)
                await asyncio.sleep(0.001)
    except TimeoutError:
        raise TimeoutError(f"{what}: not within {timeout} s") from None
    return value


def linear_is(mm: int) -> Callable[[DriveVelocity], bool]:
    return lambda c: c.linear_mm == mm


def is_zero(c: DriveVelocity) -> bool:
    return c == ZERO


async def frame(
    sim: ChassisSimulator,
    since: float,
    test: Callable[[DriveVelocity], bool],
    what: str,
    timeout: float = 2.0,
) -> float:
    """The (monotonic) time of the first velocity frame from ``since`` that passes ``test``."""

    def first() -> float | None:
        return next((t for t, c in drives(sim, since) if test(c)), None)

    return await poll(first, timeout, what)


class TelemetryLog:
    """Every telemetry frame's (monotonic time, measured linear velocity)."""

    def __init__(self, robot: Chassis) -> None:
        self.frames: list[tuple[float, float]] = []
        self._task = asyncio.ensure_future(self._run(robot))

    async def _run(self, robot: Chassis) -> None:
        async for t in robot.telemetry():
            self.frames.append((t.timestamp, t.linear))

    async def zero(self, since: float) -> float:
        """The time of the first telemetry from ``since`` that measures zero."""

        def first() -> float | None:
            return next((t for t, v in self.frames if t >= since and v == 0.0), None)

        return await poll(first, 2.0, "the measured velocity zero")

    def rate(self, start: float, end: float) -> float:
        n = sum(1 for t, _ in self.frames if start <= t <= end)
        return (n - 1) / (end - start) if n > 1 else math.nan

    def close(self) -> None:
        self._task.cancel()


#: The peer prints ``published`` when ``write()`` has returned, and Fast DDS sends within
#: ``write()``: the frame can come first, by a little. Far less than a period (50 ms).
PRINT_SLACK = 0.005


def acted_on(peer: Peer, moved: float) -> tuple[int, float]:
    """Which sample the robot moved on (0: the first), and its ``published`` -> the
    motion frame (wall clock), in s: the newest sample published before the frame."""
    published = [e for e in peer.named("published") if e["t"] <= moved + PRINT_SLACK]
    if not published:
        return 0, math.nan
    return int(published[-1]["i"]), moved - float(published[-1]["t"])


def discovery_of(peer: Peer, spawned: float) -> tuple[float, float] | None:
    """(spawned -> matched, started -> matched) of a peer, in s."""
    started = next((e["t"] for e in peer.events if e.get("event") == "started"), None)
    matched = next((e["t"] for e in peer.events if e.get("event") == "matched"), None)
    if started is None or matched is None:
        return None
    return float(matched - spawned), float(matched - started)


# --- 1-4: commands and odometry ------------------------------------------------------------


async def in_process_floors(
    sim: ChassisSimulator, robot: Chassis, log: TelemetryLog, n: int, deadmen: int
) -> dict[str, list[float]]:
    """set_velocity -> frame, stop -> zero frame, and the deadman, all in process."""
    command, stop, deadman, deadman_measured = [], [], [], []
    for i in range(n):
        mm = 100 + i
        sent = time.monotonic()
        await robot.set_velocity(mm / 1000, 0.0, duration=1.0)
        command.append(await frame(sim, sent, linear_is(mm), "set_velocity floor") - sent)
        await asyncio.sleep(0.03)
        sent = time.monotonic()
        await robot.stop()
        stop.append(await frame(sim, sent, is_zero, "stop floor") - sent)
        await asyncio.sleep(0.03)
    for _ in range(deadmen):
        await asyncio.sleep(0.3)  # measured still
        sent = time.monotonic()
        await robot.set_velocity(0.3, 0.0, duration=DEADMAN)
        stopped = await frame(sim, sent, is_zero, "deadman floor")
        deadman.append(stopped - sent)
        deadman_measured.append(await log.zero(stopped) - sent)
    return {
        "command": command,
        "stop": stop,
        "deadman": deadman,
        "deadman_measured": deadman_measured,
    }


async def teleop_alive_silent(
    sim: ChassisSimulator, robot: Chassis, log: TelemetryLog, repeats: int
) -> dict[str, Any]:
    """The deadman runs: teleop publishes 10 samples at 20 Hz, then stays alive and
    silent (``--hold``) while the deadman stops the robot."""
    first, last, measured, discovery, hop = [], [], [], [], []
    async with bridged(robot, command_timeout=DEADMAN) as bridge:
        for i in range(repeats):
            mm = 300 + 10 * i  # a value no earlier repeat had
            since = time.monotonic()
            args = ("pub", "twist", "rt/cmd_vel", "--rate", "20", "--count", "10", "--hold", "1.5")
            spawned = time.time()
            async with await start_peer(*args, "--linear", f"{mm / 1000}") as teleop:
                published = await teleop.wait_for("published", 15.0)
                moved = await frame(sim, since, linear_is(mm), "first command -> motion")
                first.append(to_wall(moved) - published["t"])
                final = await teleop.wait_for(lambda e: e.get("i") == 9, 5.0)
                hop.append(acted_on(teleop, to_wall(moved)))
                after = to_monotonic(final["t"])
                stopped = await frame(sim, after, is_zero, "deadman", DEADMAN + 1.0)
                last.append(to_wall(stopped) - final["t"])
                measured.append(to_wall(await log.zero(stopped)) - final["t"])
                if teleop.returncode is not None or teleop.named("writer_deleted"):
                    raise RuntimeError("the writer left before the deadman stopped the robot")
                discovery.append(discovery_of(teleop, spawned))
        counters = {
            "commands": bridge.commands,
            "refused": bridge.refused,
            "writer_gone_stops": bridge.writer_gone_stops,
        }
    return {
        "first": first,
        "acted_on": hop,
        "last": last,
        "measured": measured,
        "discovery": discovery,
        "bridge": counters,
    }


async def teleop_leaves(sim: ChassisSimulator, robot: Chassis, repeats: int) -> dict[str, Any]:
    """A 5 s deadman: the writer's leaving is what stops the robot."""
    first, gone, discovery, hop = [], [], [], []
    async with bridged(robot, command_timeout=5.0) as bridge:
        for i in range(repeats):
            mm = 200 + 10 * i
            since = time.monotonic()
            args = ("pub", "twist", "rt/cmd_vel", "--rate", "20", "--count", "5")
            spawned = time.time()
            async with await start_peer(*args, "--linear", f"{mm / 1000}") as teleop:
                published = await teleop.wait_for("published", 15.0)
                moved = await frame(sim, since, linear_is(mm), "first command -> motion")
                first.append(to_wall(moved) - published["t"])
                final = await teleop.wait_for(lambda e: e.get("i") == 4, 5.0)
                hop.append(acted_on(teleop, to_wall(moved)))
                deleted = await teleop.wait_for("deleting_writer", 10.0)
                after = to_monotonic(final["t"])
                stopped = await frame(sim, after, is_zero, "writer gone -> zero", 6.0)
                gone.append(to_wall(stopped) - deleted["t"])
                discovery.append(discovery_of(teleop, spawned))
        stops = bridge.writer_gone_stops
    if stops != repeats:
        raise RuntimeError(f"{stops} writer-gone stops in {repeats} runs")
    return {
        "first": first,
        "acted_on": hop,
        "gone": gone,
        "discovery": discovery,
        "writer_gone_stops": stops,
    }


async def odometry(robot: Chassis, log: TelemetryLog, duration: float) -> dict[str, Any]:
    """A Fast DDS reader of odom for ``duration`` s, and the device's rate in process."""
    lags: list[float] = []

    async def consume() -> None:
        async for sample in robot.odometry():
            lags.append(time.monotonic() - sample.timestamp)

    async with bridged(robot) as bridge:
        count = round(duration * 50) + 1  # the window: the first sample to the last
        args = ("sub", "odometry", "rt/odom", "--count", f"{count}", "--duration", "30")
        spawned = time.time()
        async with await start_peer(*args) as nav2:
            task = asyncio.ensure_future(consume())
            await nav2.wait_for("matched", 15.0)
            await nav2.wait_for("done", duration + 15.0)
            task.cancel()
        published = bridge.odometry_published
    samples = nav2.samples
    if len(samples) < 2:
        raise RuntimeError(f"the odometry reader got {len(samples)} samples")
    t0, t1 = samples[0]["t"], samples[-1]["t"]
    stamps = [e["t"] - (e["stamp"]["sec"] + e["stamp"]["nanosec"] * 1e-9) for e in samples]
    return {
        "received_hz": (len(samples) - 1) / (t1 - t0),
        "telemetry_hz": log.rate(to_monotonic(t0), to_monotonic(t1)),
        "window_s": t1 - t0,
        "stamp_to_receipt_ms": summary(stamps, 1e3),
        "in_process_ms": summary(lags, 1e3),
        "published": published,
        "discovery": [discovery_of(nav2, spawned)],
    }


async def commands_and_odometry(quick: bool) -> dict[str, Any]:
    repeats = 3 if quick else 6
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        log = TelemetryLog(robot)
        try:
            await poll(lambda: True if len(log.frames) > 5 else None, 5.0, "telemetry")
            floors = await in_process_floors(
                sim, robot, log, 10 if quick else 20, 1 if quick else 3
            )
            alive = await teleop_alive_silent(sim, robot, log, repeats)
            leaves = await teleop_leaves(sim, robot, repeats)
            odom = await odometry(robot, log, 2.0 if quick else 4.0)
        finally:
            log.close()
    return {"floors": floors, "alive_silent": alive, "leaves": leaves, "odometry": odom}


# --- 5: discovery, in a fresh process per configuration -------------------------------------


async def measure_discovery(kind: str, repeats: int, timeout: float) -> dict[str, Any]:
    """(in a child) ``repeats`` peers one after another against one fresh bridge."""
    from chassis_sdk.integrations.ros2.dds import Discovery

    discovery = Discovery()
    if kind == "localhost":
        discovery = Discovery(range="LOCALHOST")
    elif kind in ("cyclone", "index-none"):
        index = "<ParticipantIndex>none</ParticipantIndex>" if kind == "index-none" else ""
        os.environ["CYCLONEDDS_URI"] = CYCLONE_UNICAST.format(index=index)
        discovery = Discovery(range="SYSTEM_DEFAULT")
    unicast = ("--unicast",) if kind != "multicast" else ()
    spawn: list[float] = []
    times: list[float] = []
    missed = 0
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, discovery=discovery),
    ):
        for _ in range(repeats):
            args = ("sub", "odometry", "rt/odom", *unicast, "--count", "3")
            spawned = time.time()
            async with await start_peer(*args, "--duration", f"{timeout + 5}") as peer:
                try:
                    matched = await peer.wait_for("matched", timeout)
                except TimeoutError:
                    missed += 1
                    continue
                started = await peer.wait_for("started", 1.0)
                spawn.append(matched["t"] - spawned)
                times.append(matched["t"] - started["t"])
                await peer.wait_for("done", 10.0)  # and odometry flows
    return {"kind": kind, "spawned": spawn, "started": times, "missed": missed,
            "timeout": timeout}  # fmt: skip


async def discovery_child(kind: str, repeats: int, timeout: float) -> dict[str, Any]:
    cmd = [sys.executable, SELF, "--discovery", kind,
           "--repeats", str(repeats), "--timeout", str(timeout)]  # fmt: skip
    proc = await asyncio.create_subprocess_exec(*cmd, stdout=asyncio.subprocess.PIPE)
    out, _ = await proc.communicate()
    if proc.returncode:
        raise RuntimeError(f"discovery {kind}: the child failed ({proc.returncode})")
    result: dict[str, Any] = json.loads(out.decode().strip().splitlines()[-1])
    return result


# --- 6: CPU and memory, in a fresh process each --------------------------------------------


def rss_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


async def measure_cost(with_bridge: bool, window: float) -> dict[str, Any]:
    """(in a child) A simulator and a Chassis, with or without the bridge: ``ready``,
    then after ``go`` on stdin one second of warm-up and the window, as JSON."""
    async with contextlib.AsyncExitStack() as stack:
        sim = await stack.enter_async_context(ChassisSimulator())
        robot = await stack.enter_async_context(Chassis(sim.port))
        bridge = await stack.enter_async_context(bridged(robot)) if with_bridge else None
        print("ready", flush=True)
        await asyncio.to_thread(sys.stdin.readline)
        await asyncio.sleep(1.0)
        n0 = bridge.odometry_published if bridge else 0
        rss0, c0, t0, w0 = rss_bytes(), time.process_time(), time.monotonic(), time.time()
        await asyncio.sleep(window)
        c1, t1, w1, rss1 = time.process_time(), time.monotonic(), time.time(), rss_bytes()
        n1 = bridge.odometry_published if bridge else 0
        dropped = bridge.dropped_writes if bridge else 0
    return {
        "bridge": with_bridge,
        "cpu_percent": (c1 - c0) / (t1 - t0) * 100,
        "cpu_s": c1 - c0,
        "elapsed_s": t1 - t0,
        "rss_mb": rss0 / 1e6,
        "rss_growth_mb": (rss1 - rss0) / 1e6,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
        "odometry_published": n1 - n0,
        "dropped_writes": dropped,
        "window": [w0, w1],
    }


async def cost_child(with_bridge: bool, window: float) -> dict[str, Any]:
    cmd = [sys.executable, SELF, "--cost",
           "bridge" if with_bridge else "floor", "--window", str(window)]  # fmt: skip
    proc = await asyncio.create_subprocess_exec(
        *cmd, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE
    )
    assert proc.stdin is not None
    assert proc.stdout is not None
    try:
        ready = await asyncio.wait_for(proc.stdout.readline(), 30.0)
        if ready.strip() != b"ready":
            raise RuntimeError(f"cost child: {ready!r}")
        args = ("sub", "odometry", "rt/odom", "--duration", f"{window + 10}")
        peer: Peer
        async with await start_peer(*args) as peer:
            await peer.wait_for("started", 15.0)
            if with_bridge:
                await peer.wait_for(lambda e: e.get("event") == "sample", 15.0)
            proc.stdin.write(b"go\n")
            await proc.stdin.drain()
            line = await asyncio.wait_for(proc.stdout.readline(), window + 30.0)
            result: dict[str, Any] = json.loads(line)
            w0, w1 = result["window"]
            got = [e["t"] for e in peer.samples if w0 <= e["t"] <= w1]
            result["peer_received_hz"] = (len(got) - 1) / (got[-1] - got[0]) if len(got) > 1 else 0
        proc.stdin.close()
        if await asyncio.wait_for(proc.wait(), 15.0):
            raise RuntimeError(f"cost child failed ({proc.returncode})")
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    return result


# --- the run ---------------------------------------------------------------------------------


def finite(value: Any) -> Any:
    """``value`` with every NaN or infinity as ``None`` (JSON has neither)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def _cells(s: dict[str, float]) -> str:
    """n, median, p99, max."""
    if not s["n"]:
        return f"{0:>5}" + f"{'-':>9}" * 3
    return f"{s['n']:>5.0f}{s['median']:>9.1f}{s['p99']:>9.1f}{s['max']:>9.1f}"


def _floor(s: dict[str, float], what: str) -> str:
    return f"   {s['median']:.1f} / {s['max']:.1f} ms {what}"


HEAD = f"{'n':>5}{'median':>9}{'p99':>9}{'max':>9}"
WIDTH = 48


def headline(r: dict[str, Any]) -> dict[str, Any]:
    """The printed figures (ms, each with its floor) for the JSON file; the raw values
    (s) sit beside them there."""
    f = {k: summary(v, 1e3) for k, v in r["floors"].items()}
    alive, leaves, odom = r["alive_silent"], r["leaves"], r["odometry"]
    floor, bridge = r["cost"]["floor"], r["cost"]["bridge"]
    share = bridge["cpu_percent"] - floor["cpu_percent"]
    return {
        "first_command_to_motion": summary(alive["first"] + leaves["first"], 1e3),
        "first_command_to_motion_floor": f["command"],
        "sample_acted_on_to_motion": summary(
            [t for _, t in alive["acted_on"] + leaves["acted_on"] if math.isfinite(t)], 1e3
        ),
        "last_command_to_zero_frame": summary(alive["last"], 1e3),
        "last_command_to_zero_frame_floor": f["deadman"],
        "last_command_to_measured_zero": summary(alive["measured"], 1e3),
        "last_command_to_measured_zero_floor": f["deadman_measured"],
        "writer_gone_to_zero_frame": summary(leaves["gone"], 1e3),
        "writer_gone_to_zero_frame_floor": f["stop"],
        "odometry_hz": odom["received_hz"],
        "telemetry_hz_floor": odom["telemetry_hz"],
        "odometry_stamp_to_receipt": odom["stamp_to_receipt_ms"],
        "odometry_stamp_to_receipt_floor": odom["in_process_ms"],
        "discovery": {d["kind"]: summary(d["spawned"], 1e3) for d in r["discovery"]},
        "bridge_cpu_percent": share,
        "bridge_cpu_us_per_odometry": share
        / 100
        * bridge["elapsed_s"]
        / max(bridge["odometry_published"], 1)
        * 1e6,
        "bridge_rss_mb": bridge["rss_mb"] - floor["rss_mb"],
        "bridge_rss_growth_mb": bridge["rss_growth_mb"] - floor["rss_growth_mb"],
    }


def report(r: dict[str, Any], quick: bool) -> None:
    f = {k: summary(v, 1e3) for k, v in r["floors"].items()}
    alive, leaves, odom = r["alive_silent"], r["leaves"], r["odometry"]
    acted = alive["acted_on"] + leaves["acted_on"]
    later = sum(1 for i, _ in acted if i > 0)
    print(f"{'figure, ms':<{WIDTH}}{HEAD}   floor, same run: median / max")
    deadman = f"set_velocity(duration={DEADMAN:g}) in process"
    rows = [
        (
            "first cmd_vel -> its motion frame",
            alive["first"] + leaves["first"],
            _floor(f["command"], "set_velocity() -> frame, in process"),
        ),
        (
            "  the sample it moved on -> its frame",
            [t for _, t in acted if math.isfinite(t)],
            f"   it moved on a later sample in {later} of {len(acted)} runs",
        ),
        (
            "last cmd_vel, writer silent -> zero frame",
            alive["last"],
            _floor(f["deadman"], deadman) + f"; the deadman {DEADMAN * 1e3:.0f}",
        ),
        (
            "  -> the telemetry measures zero",
            alive["measured"],
            _floor(f["deadman_measured"], deadman),
        ),
        (
            "deleting_writer -> zero frame (deadman 5 s)",
            leaves["gone"],
            _floor(f["stop"], "stop() -> zero frame, in process"),
        ),
    ]
    for label, values, floor in rows:
        print(f"{label:<{WIDTH}}{_cells(summary(values, 1e3))}{floor}")
    lag, local = odom["stamp_to_receipt_ms"], odom["in_process_ms"]
    label = "odom stamp -> the Fast DDS reader's receipt"
    print(
        f"{label:<{WIDTH}}{_cells(lag)}   {local['median']:.2f} / {local['p99']:.2f} ms "
        "(p99) reading -> async for, in process"
    )
    print(
        f"{'odom at a Fast DDS reader, Hz':<{WIDTH}}{'':>5}{odom['received_hz']:>9.1f}{'':>18}"
        f"   {odom['telemetry_hz']:.1f} Hz telemetry in process, the same "
        f"{odom['window_s']:.1f} s"
    )
    print()
    print(f"{'discovery, ms: peer spawned -> matched':<{WIDTH}}{HEAD}   started -> matched: "
          "median / max; missed")  # fmt: skip
    teleop = r["dds_discovery"]
    rows2 = [(d["kind"], d["spawned"], d["started"], d["missed"], d["timeout"])
             for d in r["discovery"]]  # fmt: skip
    label = f"  multicast: the {len(teleop)} peers of the runs above"
    rows2.insert(1, (label, [d[0] for d in teleop], [d[1] for d in teleop], 0, 0.0))
    for kind, spawn, start, missed, timeout in rows2:
        s1 = summary(start, 1e3)
        both = f"{s1['median']:.1f} / {s1['max']:.1f}" if s1["n"] else "-"
        gone = f"{missed}, no match in {timeout:g} s" if missed else "0"
        print(f"{DISCOVERIES.get(kind, kind):<{WIDTH}}{_cells(summary(spawn, 1e3))}   "
              f"{both}; {gone}")  # fmt: skip
    print()
    floor, bridge = r["cost"]["floor"], r["cost"]["bridge"]
    share = bridge["cpu_percent"] - floor["cpu_percent"]
    window = bridge["elapsed_s"]
    per = share / 100 * window / max(bridge["odometry_published"], 1) * 1e6
    print(f"{f'cost at 50 Hz, {window:.0f} s windows, fresh processes':<{WIDTH}}"
          f"{'floor':>9}{'bridge':>9}{'share':>9}")  # fmt: skip
    cost_rows = [
        ("process CPU, % of one core", "cpu_percent", "9.1f"),
        ("RSS after warm-up, MB", "rss_mb", "9.1f"),
        ("RSS growth over the window, MB", "rss_growth_mb", "9.2f"),
    ]
    for label, key, fmt in cost_rows:
        a, b = floor[key], bridge[key]
        print(f"{'  ' + label:<{WIDTH}}{a:{fmt}}{b:{fmt}}{b - a:{fmt}}")
    print(
        f"  the bridge's CPU per odometry message (odom + /tf + joint_states, and the 1 Hz "
        f"battery and diagnostics): {per:.0f} us; "
        f"{bridge['odometry_published'] / window:.1f} published/s, "
        f"{bridge['peer_received_hz']:.1f}/s at the peer, {bridge['dropped_writes']} dropped"
    )
    counters = alive["bridge"]
    print(
        f"({'quick; ' if quick else ''}{len(alive['first'])} + {len(leaves['first'])} teleop "
        f"runs at 20 Hz; {counters['commands']} commands written, {counters['refused']} refused, "
        f"{leaves['writer_gone_stops']} writer-gone stops; a Fast DDS 2.9 peer, RTPS over UDP "
        "on loopback in a namespace of its own; CPU: time.process_time(), every thread)"
    )


async def run(quick: bool) -> dict[str, Any]:
    r = await commands_and_odometry(quick)
    r["dds_discovery"] = [
        d
        for d in r["alive_silent"]["discovery"]
        + r["leaves"]["discovery"]
        + r["odometry"]["discovery"]
        if d is not None
    ]
    window = 3.0 if quick else 10.0
    r["cost"] = {
        "floor": await cost_child(False, window),
        "bridge": await cost_child(True, window),
    }
    repeats = 3 if quick else 6
    r["discovery"] = [await discovery_child("multicast", repeats, 10.0)]
    multicast_off()
    r["discovery"] += [
        await discovery_child("localhost", repeats, 10.0),
        await discovery_child("cyclone", repeats, 10.0),
        await discovery_child("index-none", 1, 5.0 if quick else 10.0),
    ]
    return r


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, shorter windows")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    parser.add_argument("--cost", choices=["floor", "bridge"], help=argparse.SUPPRESS)
    parser.add_argument("--window", type=float, default=10.0, help=argparse.SUPPRESS)
    parser.add_argument("--discovery", choices=list(DISCOVERIES), help=argparse.SUPPRESS)
    parser.add_argument("--repeats", type=int, default=5, help=argparse.SUPPRESS)
    parser.add_argument("--timeout", type=float, default=10.0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if os.environ.get(NETNS) is None:
        return reexec()
    if not in_own_namespace():
        return _refuse(f"{NETNS} is set but this is the host's network namespace")
    # Cyclone's own configuration is what each measurement sets, never the caller's.
    os.environ.pop("CYCLONEDDS_URI", None)
    if args.cost:
        print(json.dumps(asyncio.run(measure_cost(args.cost == "bridge", args.window))))
        return 0
    if args.discovery:
        job = measure_discovery(args.discovery, args.repeats, args.timeout)
        print(json.dumps(asyncio.run(job)))
        return 0
    try:
        setup_namespace()
    except RuntimeError as exc:
        return _refuse(f"setting up the namespace failed: {exc}")
    print("== machine")
    lines = machine()
    lines.append(f"load before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for line in lines:
        print(line)
    print(flush=True)
    figures = asyncio.run(run(args.quick))
    report(figures, args.quick)
    after = f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    print(after)
    if args.json:
        lines.append(after)
        out = {
            "machine": dict(line.split(": ", 1) for line in lines),
            "quick": args.quick,
            "summary_ms": headline(figures),
            **figures,
        }
        Path(args.json).write_text(json.dumps(finite(out), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
