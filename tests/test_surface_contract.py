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
import math
import os
import signal
import sys
import time
import tty
from argparse import Namespace
from collections.abc import AsyncIterator, Callable
from typing import Any, ClassVar

import aiomqtt
import anyio
import pytest
import websockets
from cyclonedds.core import Listener as DdsListener
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from chassis_sdk import Chassis, MotionBlockedError
from chassis_sdk.cli.teleop_command import drive_from_terminal
from chassis_sdk.core.motion import WRITE_PERIOD
from chassis_sdk.integrations.foxglove import FoxgloveServer
from chassis_sdk.integrations.ros2.dds import Discovery
from chassis_sdk.integrations.web import WebDashboard
from chassis_sdk.protocol import Command, CommandId, DriveVelocity
from chassis_sdk.recording import ros2_types as m
from chassis_sdk.sim import ChassisSimulator
from chassis_sdk.teleop.keys import KeyTeleop

from .support.cli import ROOT
from .support.foxglove_client import FoxgloveClient
from .support.helpers import until
from .support.mqtt import bridged
from .support.mqtt_broker import broker
from .support.ros2 import bridged as ros2_bridged

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
    #: What it offers: "stop" (a stop of its own, not a zero velocity), "estop", "junk",
    #: "held_up", "two_clients", "read_only", and "streaming" (its clients repeat their
    #: command: a neutral is owed after a block).
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
    async def served(self) -> AsyncIterator[None]:
        """A simulated chassis (`sim`), its device (`robot`, with the short `DEADMAN`)
        and the surface serving it, for the block."""
        async with (
            ChassisSimulator() as self.sim,
            Chassis(self.sim.port, command_timeout=DEADMAN) as self.robot,
            self.serve(self.sim, self.robot),
        ):
            yield

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
    offers = frozenset({"stop", "estop", "junk"})
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
    offers = frozenset(
        {"stop", "estop", "junk", "held_up", "two_clients", "read_only", "streaming"}
    )
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
    offers = frozenset({"stop", "estop", "junk", "two_clients", "read_only", "streaming"})
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


class _MqttClient(Client):
    """A fleet dashboard or joystick node publishing the bridge's command topics."""

    def __init__(self, client: aiomqtt.Client, topic: str) -> None:
        self.client = client
        self.topic = topic

    async def _send(self, what: str, body: Any) -> None:
        data = body if isinstance(body, bytes) else json.dumps(body).encode()
        await self.client.publish(f"{self.topic}/cmd/{what}", data)

    async def velocity(self, linear: float, angular: float = 0.0) -> None:
        await self._send("velocity", {"linear": linear, "angular": angular})

    async def stop(self) -> None:
        await self._send("stop", b"")

    async def estop(self, engaged: bool) -> None:
        await self._send("estop", {"engaged": engaged})

    async def junk(self) -> None:
        await self._send("velocity", b'{"linear": NaN, "angular": 0}')

    async def held_up(self, linear: float) -> None:
        stamp = time.time() - DEADMAN - 0.5  # past the deadman and the clock skew allowed
        await self._send("velocity", {"linear": linear, "angular": 0.0, "timestamp": stamp})


class Mqtt(Surface):
    name = "mqtt"
    marks = (pytest.mark.mqtt,)
    # One source per bridge: MQTT does not tell a subscriber who published a message,
    # so two senders are one client to the bridge (no "two_clients"); a stop is taken
    # from anyone allowed to publish it (the broker's ACL), so no read-only twin either.
    offers = frozenset({"stop", "estop", "junk", "held_up", "streaming"})
    kind = "mqtt"

    @contextlib.asynccontextmanager
    async def serve(self, sim: ChassisSimulator, robot: Chassis) -> AsyncIterator[None]:
        async with broker() as b, bridged(b, robot, "r1"):
            self.address = f"127.0.0.1:{b.port}/robots/r1"
            async with self.connect(self.address):  # the bridge is online: it takes commands
                pass
            yield

    @classmethod
    @contextlib.asynccontextmanager
    async def connect(cls, address: str) -> AsyncIterator[Client]:
        host_port, _, topic = address.partition("/")
        host, _, port = host_port.partition(":")
        async with aiomqtt.Client(host, int(port), protocol=aiomqtt.ProtocolVersion.V5) as client:
            await client.subscribe(f"{topic}/connection")
            async with asyncio.timeout(10):
                async for message in client.messages:  # retained: the bridge's state
                    body = message.payload if isinstance(message.payload, bytes) else b"{}"
                    if json.loads(body).get("state") == "ONLINE":
                        break
            await client.unsubscribe(f"{topic}/connection")
            yield _MqttClient(client, topic)


ROS_DOMAIN = 23  # any: each ROS 2 check has a network namespace of its own


def _stamped(linear: float, angular: float = 0.0, age: float = 0.0) -> Any:
    twist = m.Twist(linear=m.Vector3(x=linear), angular=m.Vector3(z=angular))
    return m.TwistStamped(header=m.Header(stamp=m.stamp(time.time() - age)), twist=twist)


class _Ros2Client(Client):
    """A ROS 2 node (Nav2, teleop_twist_joy) on the DDS graph: ``cmd_vel`` as
    ``TwistStamped`` and ``emergency_stop``, both reliable."""

    def __init__(self, cmd_vel: Any, estop: Any) -> None:
        self.cmd_vel = cmd_vel
        self.estop_writer = estop

    async def velocity(self, linear: float, angular: float = 0.0) -> None:
        self.cmd_vel.write(_stamped(linear, angular))
        await asyncio.sleep(0)

    async def stop(self) -> None:  # ROS 2 has no stop topic: a zero Twist
        await self.velocity(0.0)

    async def estop(self, engaged: bool) -> None:
        self.estop_writer.write(m.Bool(data=engaged))
        await asyncio.sleep(0)

    async def junk(self) -> None:
        self.cmd_vel.write(_stamped(math.nan))
        await asyncio.sleep(0)

    async def held_up(self, linear: float) -> None:
        self.cmd_vel.write(_stamped(linear, age=DEADMAN + 0.5))  # past the deadman and skew
        await asyncio.sleep(0)


class Ros2(Surface):
    name = "ros2"
    marks = (pytest.mark.ros2, pytest.mark.netns)
    # Each cmd_vel writer is a source (its publication handle); a read-only bridge
    # subscribes to nothing; ROS 2 has no stop of its own (a zero Twist is a velocity:
    # the e-stop topic is its stop).
    offers = frozenset({"estop", "junk", "held_up", "two_clients", "streaming"})
    kind = "ros2"

    @contextlib.asynccontextmanager
    async def serve(self, sim: ChassisSimulator, robot: Chassis) -> AsyncIterator[None]:
        discovery = Discovery(domain_id=ROS_DOMAIN)
        async with ros2_bridged(robot, discovery=discovery, stamped=True, command_timeout=DEADMAN):
            self.address = str(ROS_DOMAIN)
            yield

    @classmethod
    @contextlib.asynccontextmanager
    async def connect(cls, address: str) -> AsyncIterator[Client]:
        dp = DomainParticipant(int(address))
        matched: dict[str, int] = {}

        def writer(name: str, tp: type) -> Any:
            def on_match(_writer: Any, status: Any) -> None:
                matched[name] = int(status.current_count)

            listener = DdsListener(on_publication_matched=on_match)  # type: ignore[no-untyped-call]
            qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10))
            return DataWriter(dp, Topic(dp, name, tp), qos, listener)

        cmd_vel = writer("rt/cmd_vel", m.TwistStamped)
        estop = writer("rt/emergency_stop", m.Bool)
        await until(
            lambda: matched.get("rt/cmd_vel", 0) > 0 and matched.get("rt/emergency_stop", 0) > 0,
            timeout=10.0,
        )
        yield _Ros2Client(cmd_vel, estop)


class _TerminalClient(Client):
    """The operator at ``chassis-sdk teleop``'s terminal: key bytes into its pty (a key
    held is its autorepeat: the same byte again and again)."""

    def __init__(self, master: int) -> None:
        self.master = master

    async def velocity(self, linear: float, angular: float = 0.0) -> None:
        os.write(self.master, b"w" if linear > 0 else b"s" if linear < 0 else b" ")
        await asyncio.sleep(0)

    async def stop(self) -> None:
        os.write(self.master, b" ")
        await asyncio.sleep(0)

    async def estop(self, engaged: bool) -> None:
        os.write(self.master, b"e" if engaged else b"r")
        await asyncio.sleep(0)


class Teleop(Surface):
    name = "teleop"
    # One terminal, one operator: no second client, no junk (a key it does not know is
    # nothing), and its keys come from this process's pty.
    offers = frozenset({"stop", "estop", "streaming"})
    kind = "teleop"
    remote = False

    @contextlib.asynccontextmanager
    async def serve(self, sim: ChassisSimulator, robot: Chassis) -> AsyncIterator[None]:
        master, slave = os.openpty()
        tty.setraw(slave)  # as `chassis-sdk teleop` sets its terminal: each key as it comes
        keys = KeyTeleop(max_linear=0.5, max_angular=1.0, speed=0.4)  # w: 0.2 m/s
        try:
            async with anyio.create_task_group() as tg:
                tg.start_soon(
                    drive_from_terminal, robot, keys, None, slave, Namespace(seconds=None)
                )
                self.master = master
                yield
                tg.cancel_scope.cancel()
        finally:
            os.close(master)
            os.close(slave)

    @contextlib.asynccontextmanager
    async def client(self, *, read_only: bool = False) -> AsyncIterator[Client]:
        yield _TerminalClient(self.master)


SURFACES: list[type[Surface]] = [Api, Web, Foxglove, Mqtt, Ros2, Teleop]


def surfaces(*needs: str, but: tuple[str, ...] = ()) -> pytest.MarkDecorator:
    """Parametrise a check over the surfaces that offer all of ``needs`` (``but`` those
    named)."""
    chosen = [s for s in SURFACES if set(needs) <= s.offers and s.name not in but]
    return pytest.mark.parametrize(
        "surface",
        [pytest.param(s, id=s.name, marks=s.marks) for s in chosen],
        indirect=True,
    )


@pytest.fixture
def surface(request: pytest.FixtureRequest) -> Surface:
    """The surface of the parameter, not yet served: each check serves it in its own
    body (``async with surface.served():``), where its task groups belong."""
    made: Surface = request.param()
    return made


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
            async with contextlib.AsyncExitStack() as stack:
                client = await stack.enter_async_context(surface.client())
                self._client = stack.pop_all()
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
            await self._client.aclose()
        proc = self._proc
        if proc is not None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
            out, _ = await proc.communicate()
            self.sent = int(out.split()[-1]) if out.strip() else 0


# --- the checks ---------------------------------------------------------------------------

pytestmark = [pytest.mark.surface, pytest.mark.integration]


@surfaces()
async def test_a_command_drives_and_the_deadman_stops_it(surface: Surface) -> None:
    async with surface.served():
        sim = surface.sim
        async with surface.client() as client:
            await client.velocity(0.2)
            await until(lambda: any(v == 200 for _, v in velocities(sim)))
            sent = time.monotonic()
            await until(lambda: velocities(sim)[-1][1] == 0, timeout=DEADMAN + 1.0)
            assert velocities(sim, sent)[-1][1] == 0


@pytest.mark.timing  # a flood from another process: not a load for parallel tests
@surfaces()
async def test_velocity_reaches_the_wire_at_most_once_per_period_under_a_flood(
    surface: Surface,
) -> None:
    async with surface.served():
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
@surfaces("stop")
async def test_a_stop_never_waits_behind_a_flood_of_10_000_commands_a_second(
    surface: Surface,
) -> None:
    async with surface.served():
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
    async with surface.served():
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
        print(
            f"{surface.name}: junk at {rate:,.0f}/s; e-stop on the wire {took * 1000:.1f} ms after"
        )
        assert took < STOP_BOUND, took


@surfaces("estop", "streaming")
async def test_releasing_the_estop_restarts_nothing(surface: Surface) -> None:
    async with surface.served():
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
    async with surface.served():
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


@surfaces(but=("api",))  # the API against itself is one source
async def test_a_surface_and_the_api_arbitrate_by_priority(surface: Surface) -> None:
    async with surface.served():
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
    async with surface.served():
        sim = surface.sim
        async with surface.client() as driver, surface.client(read_only=True) as viewer:
            await driver.velocity(0.2)
            await until(lambda: any(v == 200 for _, v in velocities(sim)))
            sent = time.monotonic()
            await viewer.stop()
            await until(lambda: any(v == 0 for _, v in velocities(sim, sent)), timeout=2.0)


@surfaces("held_up")
async def test_a_held_up_command_is_refused(surface: Surface) -> None:
    async with surface.served():
        sim = surface.sim
        async with surface.client() as client:
            start = time.monotonic()
            await client.held_up(0.2)
            await asyncio.sleep(DEADMAN)
            assert [v for _, v in velocities(sim, start) if v] == []


def _rss() -> int:
    """This process's resident memory, bytes."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.timing  # two floods from other processes: a load not to put on parallel tests
@surfaces("junk", but=("api",))
async def test_memory_stays_bounded_under_a_flood(surface: Surface) -> None:
    # Velocity is state and refusals are counted, not kept: what a flood leaves behind
    # in the robot's process stops growing once it has warmed up.
    async with surface.served():
        async with (
            Flood(surface, "velocity", rate=FLOOD_RATE),
            Flood(surface, "junk", rate=FLOOD_RATE),
        ):
            await asyncio.sleep(1.0)  # warmed up: buffers at their size
            before = _rss()
            await asyncio.sleep(2.0)
            grown = _rss() - before
        print(f"{surface.name}: {grown / 2**20:+.1f} MiB over 2 s of two floods")
        assert grown < 8 * 2**20, grown
