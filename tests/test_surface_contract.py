"""One contract for every surface that can move the robot, checked through each
surface's real protocol against the simulated chassis: the application's API, the web
dashboard's WebSocket, the Foxglove WebSocket, MQTT on mosquitto, ROS 2 over DDS in a
network namespace of its own, and terminal teleop in a pty.

Each surface is one adapter (below): how to start it, and a client's few verbs
(``velocity``, ``stop``, ``estop``, ``junk``, ``held_up``). Every check is parametrised
over the adapters that have what it needs, so a new surface gets every check by adding
one adapter. The rules themselves live once, in ``chassis_sdk.core.motion``
(``tests/test_motion_core.py`` holds them as table rows); this suite shows each surface
reaches them and adds nothing of its own in between.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import itertools
import json
import signal
import sys
import time
from collections.abc import AsyncIterator, Callable
from typing import Any, ClassVar

import pytest
import websockets

from chassis_sdk import Chassis, MotionBlockedError
from chassis_sdk.core.motion import WRITE_PERIOD
from chassis_sdk.integrations.foxglove import FoxgloveServer
from chassis_sdk.integrations.web import WebDashboard
from chassis_sdk.protocol import Command, CommandId, DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.cli import ROOT
from .support.foxglove_client import FoxgloveClient
from .support.helpers import until

#: The deadman of every device here (s): short, so the checks that wait for it are too.
DEADMAN = 0.4
#: How long a stop or an e-stop may take to reach the wire through a surface (s).
STOP_BOUND = 0.05
#: Messages a second of a flood (junk, or velocity) a stop or an e-stop must get through.
FLOOD_RATE = 10_000


# --- what every check reads off the wire ----------------------------------------------


def velocities(sim: ChassisSimulator, since: float = -1e9) -> list[tuple[float, int]]:
    """``(arrival, linear mm/s)`` of every velocity frame the chassis read after ``since``."""
    return [
        (t, c.linear_mm)
        for t, c in list(sim.firmware.received)
        if t >= since and isinstance(c, DriveVelocity)
    ]


def estops(sim: ChassisSimulator, since: float = -1e9) -> list[tuple[float, int]]:
    """``(arrival, value)`` of every 0x03 (e-stop) the chassis read after ``since``."""
    return [
        (t, c.value)
        for t, c in list(sim.firmware.received)
        if t >= since and isinstance(c, Command) and c.id == CommandId.EMERGENCY_STOP
    ]


def reversals(frames: list[tuple[float, int]]) -> int:
    """How often the sign of the commanded linear velocity flips."""
    signs = [1 if v > 0 else -1 for _, v in frames if v]
    return sum(1 for a, b in itertools.pairwise(signs) if a != b)


# --- the adapters -----------------------------------------------------------------------


class Client(abc.ABC):
    """One client of a surface: a page, a WebSocket connection, an MQTT sender, a DDS
    writer, a terminal."""

    @abc.abstractmethod
    async def velocity(self, linear: float, angular: float = 0.0) -> None:
        """Send one velocity command as this client."""

    @abc.abstractmethod
    async def stop(self) -> None:
        """Send a stop as this client."""

    async def estop(self, engaged: bool) -> None:
        """Engage or release the e-stop as this client."""
        raise NotImplementedError

    async def junk(self) -> None:
        """Send one message the surface must refuse (malformed, out of range)."""
        raise NotImplementedError

    async def held_up(self, linear: float) -> None:
        """Send a velocity command that the surface must see as held up (older than
        the deadman by its stamp, or behind a stalled path)."""
        raise NotImplementedError


class Surface(abc.ABC):
    """A surface's adapter: starts it on a simulated chassis and makes clients."""

    #: The pytest id, and the markers its checks carry.
    name: ClassVar[str]
    marks: ClassVar[tuple[pytest.MarkDecorator, ...]] = ()
    #: What it offers: "estop", "junk", "held_up", "two_clients", "read_only", and
    #: "streaming" (its clients repeat their command: a neutral is owed after a block).
    offers: ClassVar[frozenset[str]] = frozenset()
    #: Its sources' kind in the motion core (for its priority against the API).
    kind: ClassVar[str]
    #: Its clients are other programs (a flood comes from a process of its own).
    remote: ClassVar[bool] = True

    sim: ChassisSimulator
    robot: Chassis
    #: Where its clients reach it (set by `serve`): what `connect` takes.
    address = ""

    @abc.abstractmethod
    def serve(
        self, sim: ChassisSimulator, robot: Chassis
    ) -> contextlib.AbstractAsyncContextManager[None]:
        """Run the surface for ``robot`` for the duration of the block (and set
        `address`)."""

    @classmethod
    def connect(cls, address: str) -> contextlib.AbstractAsyncContextManager[Client]:
        """A client of the surface at ``address`` (in any process)."""
        raise NotImplementedError

    def read_only(self) -> contextlib.AbstractAsyncContextManager[str]:
        """A read-only twin of the surface on the same robot, for the block: its address."""
        raise NotImplementedError

    @contextlib.asynccontextmanager
    async def client(self, *, read_only: bool = False) -> AsyncIterator[Client]:
        """A new client (``read_only``: one the surface lets only stop)."""
        if not read_only:
            async with self.connect(self.address) as client:
                yield client
        else:
            async with self.read_only() as address, self.connect(address) as client:
                yield client


class _ApiClient(Client):
    def __init__(self, robot: Chassis) -> None:
        self.robot = robot

    async def velocity(self, linear: float, angular: float = 0.0) -> None:
        with contextlib.suppress(MotionBlockedError):  # the API's refusal raises
            await self.robot.set_velocity(linear, angular)

    async def stop(self) -> None:
        await self.robot.stop()

    async def estop(self, engaged: bool) -> None:
        if engaged:
            await self.robot.emergency_stop()
        else:
            await self.robot.release_emergency_stop()

    async def junk(self) -> None:
        with contextlib.suppress(ValueError):
            await self.robot.set_velocity(float("nan"), 0.0)


class Api(Surface):
    name = "api"
    remote = False
    offers = frozenset({"estop", "junk"})
    kind = "api"

    @contextlib.asynccontextmanager
    async def serve(self, sim: ChassisSimulator, robot: Chassis) -> AsyncIterator[None]:
        yield

    @contextlib.asynccontextmanager
    async def client(self, *, read_only: bool = False) -> AsyncIterator[Client]:
        yield _ApiClient(self.robot)


class _WebClient(Client):
    """A dashboard page as its script is one: a WebSocket, its page clock in ``t``."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws

    async def _send(self, **message: Any) -> None:
        await self.ws.send(json.dumps(message))

    async def velocity(self, linear: float, angular: float = 0.0, *, late: float = 0.0) -> None:
        t = (time.monotonic() - late) * 1000
        await self._send(type="drive", linear=linear, angular=angular, t=t)

    async def stop(self) -> None:
        await self._send(type="stop")

    async def estop(self, engaged: bool) -> None:
        if engaged:
            await self._send(type="estop")
            await self._send(type="stop")  # the page lets go of its controls with it
        else:
            await self._send(type="release")

    async def junk(self) -> None:
        await self.ws.send('{"type": "drive", "linear": NaN, "angular": 0}')

    async def held_up(self, linear: float) -> None:
        await self.velocity(0.0)  # the page's clock, as the dashboard first sees it
        await self.velocity(linear, late=DEADMAN + 0.2)  # a backlog delivered late


class Web(Surface):
    name = "web"
    offers = frozenset({"estop", "junk", "held_up", "two_clients", "read_only", "streaming"})
    kind = "web"

    @contextlib.asynccontextmanager
    async def serve(self, sim: ChassisSimulator, robot: Chassis) -> AsyncIterator[None]:
        async with WebDashboard(robot, port=0) as web:
            self.address = f"ws://127.0.0.1:{web.port}/ws"
            yield

    @contextlib.asynccontextmanager
    async def read_only(self) -> AsyncIterator[str]:
        # A read-only dashboard on the same robot: its pages offer STOP and E-STOP.
        async with WebDashboard(self.robot, port=0, read_only=True) as web:
            yield f"ws://127.0.0.1:{web.port}/ws"

    @classmethod
    @contextlib.asynccontextmanager
    async def connect(cls, address: str) -> AsyncIterator[Client]:
        async with websockets.connect(address) as ws:
            json.loads(await ws.recv())  # the hello

            async def drain() -> None:  # states and notes: read, as a page does
                with contextlib.suppress(Exception):
                    async for _ in ws:
                        pass

            reader = asyncio.ensure_future(drain())
            try:
                yield _WebClient(ws)
            finally:
                reader.cancel()


def _twist(linear: float, angular: float) -> bytes:
    return json.dumps({"linear": {"x": linear}, "angular": {"z": angular}}).encode()


class _FoxgloveClient(Client):
    """A Foxglove app's Teleop panel and its service calls, on the Foxglove protocol."""

    def __init__(self, client: FoxgloveClient) -> None:
        self.client = client

    async def velocity(self, linear: float, angular: float = 0.0) -> None:
        await self.client.publish(1, _twist(linear, angular))

    async def stop(self) -> None:
        await self.client.call("stop")

    async def estop(self, engaged: bool) -> None:
        await self.client.call("emergency_stop" if engaged else "release_emergency_stop")

    async def junk(self) -> None:
        await self.client.publish(1, b'{"linear": {"x": NaN}}')


class Foxglove(Surface):
    name = "foxglove"
    offers = frozenset({"estop", "junk", "two_clients", "read_only", "streaming"})
    kind = "foxglove"

    @contextlib.asynccontextmanager
    async def serve(self, sim: ChassisSimulator, robot: Chassis) -> AsyncIterator[None]:
        async with FoxgloveServer(robot, port=0) as server:
            self.address = server.url
            yield

    @contextlib.asynccontextmanager
    async def read_only(self) -> AsyncIterator[str]:
        # A read-only server on the same robot: it offers stop and e-stop only.
        async with FoxgloveServer(self.robot, port=0, read_only=True) as server:
            yield server.url

    @classmethod
    @contextlib.asynccontextmanager
    async def connect(cls, address: str) -> AsyncIterator[Client]:
        async with FoxgloveClient(address) as client:
            await client.wait_for(lambda: "stop" in client.services)
            await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")
            yield _FoxgloveClient(client)


SURFACES: list[type[Surface]] = [Api, Web, Foxglove]


def surfaces(*needs: str) -> pytest.MarkDecorator:
    """Parametrise a check over the surfaces that offer all of ``needs``."""
    chosen = [s for s in SURFACES if set(needs) <= s.offers]
    return pytest.mark.parametrize(
        "surface",
        [pytest.param(s, id=s.name, marks=s.marks) for s in chosen],
        indirect=True,
    )


@pytest.fixture
async def surface(request: pytest.FixtureRequest) -> AsyncIterator[Surface]:
    made: Surface = request.param()
    async with ChassisSimulator() as sim, Chassis(sim.port, command_timeout=DEADMAN) as robot:
        made.sim, made.robot = sim, robot
        async with made.serve(sim, robot):
            yield made


async def streaming(client: Client, linear: float, rate: float) -> None:
    """Send ``linear`` at ``rate`` commands a second until cancelled."""
    while True:
        await client.velocity(linear)
        await asyncio.sleep(1 / rate)


#: A flood from another program: ``python -c _FLOODER SURFACE ADDRESS ACTION RATE``
#: (from the repository's root) connects as a client of the surface, prints
#: ``flooding``, sends ``ACTION`` (``junk`` or ``velocity``) at ``RATE`` a second (0: as
#: fast as it goes) until SIGTERM, then prints how many it sent.
_FLOODER = (
    "import sys; from tests.test_surface_contract import flood_main; flood_main(sys.argv[1:])"
)


def flood_main(argv: list[str]) -> None:
    """The flooding program (see `_FLOODER`)."""
    name, address, action, rate = argv[0], argv[1], argv[2], float(argv[3])
    surface = next(s for s in SURFACES if s.name == name)

    async def main() -> int:
        stop = asyncio.Event()
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
        async with surface.connect(address) as client:
            print("flooding", flush=True)
            return await flood(client, action, rate or None, stop.is_set)

    print(asyncio.run(main()), flush=True)


async def flood(client: Client, action: str, rate: float | None, done: Callable[[], bool]) -> int:
    """Send ``action`` as ``client`` at ``rate`` a second (``None``: as fast as it goes)
    until ``done()``; return how many were sent."""
    sent, start = 0, time.monotonic()
    while not done():
        if action == "junk":
            await client.junk()
        else:
            await client.velocity(0.1 + 0.1 * (sent % 2))
        sent += 1
        if sent % 10 == 0:
            ahead = 0.0 if rate is None else sent / rate - (time.monotonic() - start)
            await asyncio.sleep(max(0.0, ahead))
    return sent


class Flood:
    """A client sending ``action`` (``"junk"`` or ``"velocity"``) as fast as it can (or
    at ``rate`` a second), as another program would: a process of its own for a surface
    reached over a network (the flood's own work is not the robot's process's), a task
    in this loop for the API. ``sent`` is how many it sent, once it has ended."""

    def __init__(self, surface: Surface, action: str, rate: float | None = None) -> None:
        self.surface = surface
        self.action = action
        self.rate = rate
        self.sent = 0
        self._done = False
        self._proc: asyncio.subprocess.Process | None = None
        self._task: asyncio.Task[int] | None = None

    async def __aenter__(self) -> Flood:
        surface = self.surface
        if not surface.remote:
            client = _ApiClient(surface.robot)
            self._task = asyncio.ensure_future(
                flood(client, self.action, self.rate, lambda: self._done)
            )
            return self
        self._proc = proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", _FLOODER,
            surface.name, surface.address, self.action, str(self.rate or 0),
            stdout=asyncio.subprocess.PIPE, cwd=ROOT,
        )  # fmt: skip
        assert proc.stdout is not None
        async with asyncio.timeout(20):
            line = await proc.stdout.readline()
        assert line.startswith(b"flooding"), line
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._done = True
        if self._task is not None:
            self.sent = await self._task
        proc = self._proc
        if proc is not None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
            out, _ = await proc.communicate()
            self.sent = int(out.split()[-1]) if out.strip() else 0


# --- the checks ---------------------------------------------------------------------------

pytestmark = pytest.mark.integration


@surfaces()
async def test_a_command_drives_and_the_deadman_stops_it(surface: Surface) -> None:
    sim = surface.sim
    async with surface.client() as client:
        await client.velocity(0.2)
        await until(lambda: any(v == 200 for _, v in velocities(sim)))
        sent = time.monotonic()
        await until(lambda: velocities(sim)[-1][1] == 0, timeout=DEADMAN + 1.0)
        assert velocities(sim, sent)[-1][1] == 0


@pytest.mark.timing
@surfaces()
async def test_velocity_reaches_the_wire_at_most_once_per_period_under_a_flood(
    surface: Surface,
) -> None:
    sim = surface.sim

    start = time.monotonic()
    async with Flood(surface, "velocity", rate=FLOOD_RATE) as flooding:
        await asyncio.sleep(1.0)
        took = time.monotonic() - start
    sent = flooding.sent
    frames = [t for t, v in velocities(sim, start) if v and t <= start + took]
    print(f"{surface.name}: {sent} commands in {took:.2f} s, {len(frames)} velocity frames")
    assert sent > 2 * took / WRITE_PERIOD, "not a flood"
    assert len(frames) <= took / WRITE_PERIOD + 3, len(frames)


@pytest.mark.timing
@surfaces()
async def test_a_stop_never_waits_behind_a_flood_of_10_000_commands_a_second(
    surface: Surface,
) -> None:
    sim = surface.sim

    async with surface.client() as stopper, Flood(surface, "velocity", rate=FLOOD_RATE):
        await until(lambda: any(v for _, v in velocities(sim)))
        sent = time.monotonic()
        await stopper.stop()
        await until(lambda: any(v == 0 for _, v in velocities(sim, sent)), timeout=2.0)
        took = next(t for t, v in velocities(sim, sent) if v == 0) - sent
    print(f"{surface.name}: stop on the wire {took * 1000:.1f} ms after it was sent")
    assert took < STOP_BOUND, took


@pytest.mark.timing
@surfaces("estop", "junk")
async def test_an_estop_under_10_000_junk_messages_a_second_reaches_the_wire_at_once(
    surface: Surface,
) -> None:
    sim = surface.sim

    async with surface.client() as operator:
        async with Flood(surface, "junk", rate=FLOOD_RATE) as flooding:
            await asyncio.sleep(0.3)
            sent = time.monotonic()
            await operator.estop(True)
            await until(lambda: bool(estops(sim, sent)), timeout=2.0)
            took = estops(sim, sent)[0][0] - sent
            ended = time.monotonic()
        rate = flooding.sent / (ended - sent + 0.3)
        await operator.estop(False)
    print(f"{surface.name}: junk at {rate:,.0f}/s; e-stop on the wire {took * 1000:.1f} ms after")
    assert took < STOP_BOUND, took


@surfaces("estop", "streaming")
async def test_releasing_the_estop_restarts_nothing(surface: Surface) -> None:
    sim, robot = surface.sim, surface.robot
    async with surface.client() as driver, surface.client() as operator:
        stream = asyncio.ensure_future(streaming(driver, 0.2, rate=10))
        try:
            await until(lambda: any(v for _, v in velocities(sim)))
            await operator.estop(True)
            await until(lambda: "SOFTWARE_ESTOP" in robot.motion.blocks)
            await operator.estop(False)
            await until(lambda: not robot.motion.blocks)
            released = time.monotonic()
            await asyncio.sleep(DEADMAN + 0.3)  # the stream goes on all this while
            assert [v for _, v in velocities(sim, released) if v] == []
        finally:
            stream.cancel()
        # A neutral first, then the same command drives again.
        await driver.stop()
        await driver.velocity(0.2)
        await until(lambda: any(v for _, v in velocities(sim, released)))


@surfaces("two_clients")
async def test_two_clients_of_one_surface_do_not_drive_against_each_other(
    surface: Surface,
) -> None:
    sim = surface.sim
    async with surface.client() as first, surface.client() as second:
        await first.velocity(0.3)
        await until(lambda: any(v == 300 for _, v in velocities(sim)))
        start = time.monotonic()
        a = asyncio.ensure_future(streaming(first, 0.3, rate=20))
        b = asyncio.ensure_future(streaming(second, -0.3, rate=20))
        await asyncio.sleep(1.0)
        a.cancel()
        b.cancel()
        frames = velocities(sim, start)
    print(f"{surface.name}: {reversals(frames)} reversals in {len(frames)} frames")
    assert reversals(frames) == 0
    assert all(v >= 0 for _, v in frames)  # the second was refused: the first drives


@surfaces()
async def test_a_surface_and_the_api_arbitrate_by_priority(surface: Surface) -> None:
    if surface.kind == "api":
        pytest.skip("the API against itself is one source")
    sim, robot = surface.sim, surface.robot
    surface_first = robot.motion.priorities[surface.kind] > robot.motion.priorities["api"]
    async with surface.client() as client:
        if surface_first:  # the surface drives; the application is refused
            await client.velocity(0.2)
            await until(lambda: robot.motion.driver is not None)
            with pytest.raises(MotionBlockedError, match="driven by") as caught:
                await robot.set_velocity(-0.2, 0.0)
            assert caught.value.reasons == ("DRIVEN",)
        else:  # the application drives; the surface is refused
            await robot.set_velocity(-0.2, 0.0, duration=1.0)
            start = time.monotonic()
            await client.velocity(0.2)
            await asyncio.sleep(0.3)
            assert all(v <= 0 for _, v in velocities(sim, start))
            assert robot.motion.driver == "api"


@surfaces("read_only")
async def test_a_read_only_client_can_stop(surface: Surface) -> None:
    sim = surface.sim
    async with surface.client() as driver, surface.client(read_only=True) as viewer:
        await driver.velocity(0.2)
        await until(lambda: any(v == 200 for _, v in velocities(sim)))
        sent = time.monotonic()
        await viewer.stop()
        await until(lambda: any(v == 0 for _, v in velocities(sim, sent)), timeout=2.0)


@surfaces("held_up")
async def test_a_held_up_command_is_refused(surface: Surface) -> None:
    sim = surface.sim
    async with surface.client() as client:
        start = time.monotonic()
        await client.held_up(0.2)
        await asyncio.sleep(DEADMAN)
        assert [v for _, v in velocities(sim, start) if v] == []
