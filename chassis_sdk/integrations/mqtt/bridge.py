"""Robots on an MQTT broker: `MqttBridge` puts one device on a broker the user
already runs, with the deadman kept end to end.

Topics (``{p}`` the prefix, ``{id}`` the robot id; payloads JSON, SI units, field names
as in the Python types):

==============================  ====  ========  ==========================================
topic                           dir   retained  payload
==============================  ====  ========  ==========================================
``{p}/{id}/connection``         out   yes       ``{"state": "ONLINE" | "OFFLINE" |
                                                "CONNECTIONBROKEN", "timestamp": ...,
                                                "owner": ...}``
``{p}/{id}/link``               out   yes       ``{"state": "connected" | "stale" | ...}``
``{p}/{id}/info``               out   yes       the device's identity
``{p}/{id}/telemetry/{stream}`` out   no        the latest message, at most ``rate``/s
``{p}/{id}/events``             out   no        each ``RobotEvent`` (QoS 1)
``{p}/{id}/cmd/velocity``       in    never     ``{"linear": m/s, "angular": rad/s}``
``{p}/{id}/cmd/stop``           in    never     anything: zero now
``{p}/{id}/cmd/estop``          in    never     ``{"engaged": true | false}``
``{p}/{id}/errors``             out   no        what was refused: the first at once, then
                                                at most one summary per second
``{p}/{id}/request/{name}``     in    never     MQTT 5 request/response: ``get_*``, diagnose
``{p}/{id}/probe``              both  never     the bridge's probe of the broker -> bridge
                                                path, to itself: ``{"owner": ..., "probe": n}``
==============================  ====  ========  ==========================================

Why it is shaped this way
-------------------------
A command must never move the robot late. Commands are QoS 0 on a clean session (a
broker keeps nothing for a bridge that is away), a retained or stale command is
refused (one whose MQTT 5 message expiry has passed the broker never delivers), and
each velocity command is one command under the SDK's deadman
(``command_timeout``, counted from its ``timestamp`` when it has one): a dashboard
that dies, or a Wi-Fi drop, stops the robot within half a second. A command without a
``timestamp`` cannot tell its age, so the bridge probes the broker -> bridge path (a
small message to itself every 150 ms): one that arrives while that probe shows the
path held up for longer than the deadman is refused (a stalled TCP path delivers what
it held all at once when it recovers). Losing the broker
writes zero at once, and nothing moves the robot again but a new command after the
bridge is back. The connection topic follows VDA 5050: ``ONLINE`` while bridged,
``OFFLINE`` after a clean stop, and the broker publishes the last will
``CONNECTIONBROKEN`` when the bridge vanishes, or ends on an error of its own (it then
disconnects with reason 0x04, "with Will Message").

Messages come from a network the robot does not control, so nothing about one may
end the bridge, and no rate of them may delay a stop. Both are settled where a
message enters: the client's incoming queue is a `CommandInbox`, and each
message is sorted as paho hands it over, in bounded work, before anything waits:

- junk, a retained command, a stale one, an unknown topic: refused there and then
  (counted; reported on ``errors`` by a reporter of its own, at most once a second),
  never queued;
- ``cmd/stop`` and ``cmd/estop``: a lane of their own, served first, and they cancel
  any velocity command that came before them; they are never dropped (a run of them
  collapses to what it means: engaged if any engaged, stopped, released last if so);
- ``cmd/velocity``: one slot, the newest valid command: velocity is state, not a
  queue, so a flood leaves at most one pending command and the deadman runs from the
  last one the sender published; each is offered to the bridge's source in the
  device's motion core, which paces the writes and refuses it while an e-stop (or
  another block) holds or another source drives;
- ``request/...``: a short bounded queue served by two workers of their own, so a slow
  device request never holds a command up.

Memory is therefore bounded whatever arrives (a lane holds at most a few messages).

Two bridges must never drive for one robot id. Each bridge has an owner id (host,
process, random) that it puts in its ``connection`` payload; before it acts on any
command it publishes ``ONLINE`` and reads the topic back (commands routed before its
``ONLINE`` are dropped: they may have reached the previous owner; those after it are
held): if the message before its own says another owner is ``ONLINE``, it drops what
it held, puts that message back and refuses to start (`RobotIdTaken`), unless
it was told to take over. A running bridge that sees a
take-over stops taking commands at once (in the order the broker delivered them, so
no command routed to the new bridge reaches the old one), stops its robot and ends
with `RobotIdTaken`.

How it is built
---------------
`MqttBridge` is the one object its user talks to, and it holds the bridge's
lifetime: entering the client, the task group its loops run in, the stop of the robot
whatever the end, ``OFFLINE`` on a clean stop and the disconnect with reason 0x04 on
an error of its own. Its collaborators do the rest, by job, each given a narrow,
frozen context of the bridge's options (`context`), never the bridge: the
`CommandInbox` and its lanes (`inbox`), the publishing side (`publish`: the retained
topics, telemetry, events, ``errors`` and the last will; what the device produces
reaches it by callback, inside the device's read path, and one task publishes it all,
however many streams), the robot id's ownership (`ownership`) and the command side
(`commands`: sorting, velocity, stop, e-stop and requests). What aiomqtt does not
offer publicly is reached in one place (`internals`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Coroutine
from typing import Any

import aiomqtt
import anyio
from anyio.abc import TaskGroup
from paho.mqtt import client as paho
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.reasoncodes import ReasonCode

from ...core.device import Device
from ...core.validation import check_real
from ...devices import DeviceProfile, profile
from ...errors import ChassisError
from ..inbound import CommandError as CommandError  # re-exported: it was defined here
from ..inbound import check_topic_level
from .commands import REQUEST_WORKERS, Commands
from .context import CommandContext, OwnershipContext, PublishContext
from .inbox import CommandInbox, install_batched_reads, install_inbox
from .internals import client_internals
from .ownership import Ownership, RobotIdTaken, new_owner
from .publish import Publisher, connection_will

__all__ = [
    "CommandError",
    "CommandInbox",
    "MqttBridge",
    "RobotIdTaken",
    "connection_will",
    "new_owner",
]

_log = logging.getLogger("chassis_sdk.integrations.mqtt")

#: The disconnect reason that makes the broker publish the last will (MQTT 5 §3.14.2.1).
_DISCONNECT_WITH_WILL = 0x04


def _deadman(device: Device[Any, Any]) -> float:
    """The device's ``command_timeout`` (its deadman), or 0.5 s if it has none."""
    timeout = device.command_timeout
    return 0.5 if timeout is None else float(timeout)


class MqttBridge:
    """One device on an MQTT broker.

    Args:
        device: A connected (or connecting) device; the bridge never closes it.
        client: An ``aiomqtt.Client``, not yet entered, made with
            ``will=connection_will(robot_id, prefix, owner)``, MQTT 5
            (``protocol=aiomqtt.ProtocolVersion.V5``), a clean start, a client id of
            its own (two bridges must never share one) and ``queue_type=CommandInbox``:
            the bridge enters it in `run`.
        robot_id: The robot's name under the prefix (letters, digits, ``-``, ``_``).
        prefix: The first topic level.
        rate: Most telemetry messages per stream per second (the latest, never a
            backlog).
        read_only: Never subscribe to commands (requests are still answered).
        owner: This bridge's owner id, published in ``connection`` (default: a new
            `new_owner`). Keep one across reconnects of one service.
        take_over: Start even if another bridge is ``ONLINE`` for this robot id; that
            bridge stops its robot and ends.
        require_timestamp: Refuse velocity commands and e-stop releases without a
            ``timestamp``.
        max_age: The oldest a command may be, by its ``timestamp`` (seconds; plus
            `chassis_sdk.integrations.inbound.TIMESTAMP_SKEW`); default the device's
            ``command_timeout`` (0.5 if it has none). A stamped velocity command holds
            only until its stamp plus ``command_timeout`` (plus the skew), by this
            computer's clock: its age is never given back to it.
        report_interval: Least seconds between two reports on ``errors``.

    Raises:
        ValueError: A bad robot id, prefix, rate, max_age or report_interval.
        TypeError: The client's incoming queue cannot be replaced.
    """

    def __init__(
        self,
        device: Device[Any, Any],
        client: aiomqtt.Client,
        robot_id: str,
        *,
        prefix: str = "robots",
        rate: float = 10.0,
        read_only: bool = False,
        owner: str | None = None,
        take_over: bool = False,
        require_timestamp: bool = False,
        max_age: float | None = None,
        report_interval: float = 1.0,
    ) -> None:
        check_topic_level(robot_id, "robot_id")
        check_topic_level(prefix, "prefix")
        rate = check_real(rate, "rate", low=0, low_open=True, high=100, unit="per second")
        #: The device's deadman: a stamped command holds until its stamp plus this.
        self.deadman = _deadman(device)
        if max_age is None:
            max_age = self.deadman
        max_age = check_real(max_age, "max_age", low=0, low_open=True, unit="s")
        report_interval = check_real(report_interval, "report_interval", low=0, low_open=True)
        self.device = device
        self.client = client
        self.robot_id = robot_id
        self.prefix = prefix
        self.rate = float(rate)
        self.read_only = read_only
        self.owner = owner if owner is not None else new_owner()
        self.take_over = take_over
        self.require_timestamp = require_timestamp
        self.max_age = float(max_age)
        self.topic = f"{prefix}/{robot_id}"
        self.profile: DeviceProfile = profile(device.device_name)
        # Its collaborators, by job: what it publishes, who owns the robot id, and
        # what it does with what comes in (sorted into the inbox's lanes as it comes),
        # each given only what it reads.
        published = PublishContext(
            client=client,
            topic=self.topic,
            device=device,
            profile=self.profile,
            owner=self.owner,
            rate=self.rate,
        )
        self._out = Publisher(published, float(report_interval))
        self._inbox = install_inbox(client)
        install_batched_reads(client)
        owned = OwnershipContext(
            client=client, topic=self.topic, owner=self.owner, take_over=take_over
        )
        self._ownership = Ownership(owned, self._out, self._inbox.lanes)
        commanded = CommandContext(
            client=client,
            topic=self.topic,
            prefix=prefix,
            device=device,
            profile=self.profile,
            owner=self.owner,
            read_only=read_only,
            require_timestamp=require_timestamp,
            max_age=self.max_age,
            deadman=self.deadman,
        )
        self._in = Commands(commanded, self._out, self._ownership, self._inbox.lanes)
        self._inbox.sort = self._in.sort
        if not read_only:  # the probe of the broker -> bridge path (see Commands)
            self._out.probe = self._in.path

    @property
    def rejected(self) -> int:
        """Messages refused so far (each counted; reported on ``errors``, summarised)."""
        return self._out.refusals.total

    @property
    def unpublished(self) -> int:
        """Events and link states dropped unpublished (the oldest first) because the
        broker fell more than the device's ``queue_size`` behind them. Telemetry is
        never counted: each stream publishes its newest message, by design."""
        return self._out.unpublished

    @property
    def telemetry_skipped(self) -> int:
        """Telemetry slots skipped because the slot before had not left for the broker
        yet (a broker reading slowly, a congested link): the newest readings go out at
        the next slot instead, so the outgoing queue never grows."""
        return self._out.telemetry_skipped

    @property
    def online(self) -> bool:
        """True once this bridge is the robot id's owner on the broker (it has read its
        own ``ONLINE`` back and found no other bridge before it)."""
        return self._ownership.online

    @property
    def _echoed(self) -> asyncio.Event:
        # Set when the broker sent this bridge's ONLINE back (a test sets it to skip
        # the claim).
        return self._ownership.echoed

    @property
    def superseded(self) -> int:
        """Commands dropped unacted because a newer one (or a stop) made them moot."""
        return self._inbox.lanes.superseded

    @property
    def held_up(self) -> int:
        """Velocity commands without a timestamp refused as held up on their way: they
        arrived while the bridge's probe showed the broker -> bridge path holding what
        it carries for longer than the deadman."""
        return self._in.held_up

    @property
    def dropped(self) -> int:
        """Commands never acted on for ownership: routed before this bridge's ONLINE,
        or after another bridge took over."""
        return self._in.dropped

    async def run(self) -> None:
        """Bridge until cancelled (then publish ``OFFLINE``) or the broker is lost.

        The device is stopped (zero velocity) whenever this returns or raises, unless
        the bridge is ``read_only`` (a viewer never writes to the device). If it
        ends on an error of its own, it disconnects so that the broker publishes the
        last will (``CONNECTIONBROKEN``).

        Raises:
            aiomqtt.MqttError: The broker connection failed or was lost; the robot was
                stopped first. Call `run` again with a new client to resume.
            RobotIdTaken: Another bridge is ``ONLINE`` for this robot id (this one
                never took a command), or it took over (this one stopped its robot).
        """
        # The bridge's work runs in a task group, and this task awaits nothing else
        # while it runs: leaving the group cancels the workers until they are done,
        # however often a library loses a cancellation (aiomqtt's calls use
        # asyncio.wait_for, which can before Python 3.12).
        if not self.read_only:
            # The bridge's source in the motion core, from the start: an e-stop while
            # it runs asks it for a neutral (a zero, or a stop) before it drives again.
            self._in.source()
        try:
            async with self.client:
                failure: BaseException | None = None
                try:
                    async with anyio.create_task_group() as tg:
                        tg.start_soon(self._serve, tg, name=f"bridge start:{self.topic}")
                except anyio.get_cancelled_exc_class():
                    # A clean stop says OFFLINE (if this bridge got as far as owning
                    # the robot id), bounded, even under a cancelled scope.
                    with anyio.CancelScope(shield=True):
                        if self._ownership.online:  # else the connection topic is not ours
                            await self._out.offline()
                    raise
                except BaseExceptionGroup as group:
                    failure = _first_error(group)
                if failure is not None:
                    await self._ended_by(failure)
                    raise failure
        except aiomqtt.MqttError as exc:
            _log.warning("%s: broker lost (%s); the robot is stopped", self.topic, exc)
            raise
        finally:
            with anyio.CancelScope(shield=True):
                await self._stop_robot()
                self._in.close()

    async def _serve(self, tg: TaskGroup) -> None:
        """Claim the robot id, then start the bridge's loops (in ``tg``)."""
        await self._start()
        for name, work in self._loops():
            tg.start_soon(work, name=f"bridge {name}:{self.topic}")

    async def _ended_by(self, failure: BaseException) -> None:
        """One of the bridge's tasks failed with ``failure`` (the others are done)."""
        if isinstance(failure, aiomqtt.MqttError | RobotIdTaken):
            # The broker is gone, or another bridge owns the robot id: either way
            # nothing of ours may be published now.
            return
        if isinstance(failure, Exception):
            await self._stop_robot()  # first the robot, then the fleet
            await self._fail_loudly()
        # KeyboardInterrupt, SystemExit: the process ends.

    async def _start(self) -> None:
        await self._ownership.claim(self._in.subscribe)
        await self._out.info()

    def _loops(self) -> list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]]:
        loops: list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]] = [
            ("commands", self._commands),
            ("owner", self._ownership.watch),
            ("errors", self._out.reporter),
            # One task publishes everything that goes out (link, events, telemetry of
            # every stream), fed by the device's callbacks: none per stream.
            ("publish", self._events),
        ]
        return loops + [(f"requests {n}", self._in.answer_requests) for n in range(REQUEST_WORKERS)]

    # The commands and publishing loops keep their names on the bridge: a test drives
    # the first with a client of its own, and puts a failing second in (``_events``:
    # the name it had when it published only the events).

    async def _commands(self) -> None:
        await self._in.consume()

    async def _events(self) -> None:
        await self._out.run()

    async def _fail_loudly(self) -> None:
        """The bridge ends on an error of its own: tell the fleet. A DISCONNECT with
        reason 0x04 makes the broker publish the last will (``CONNECTIONBROKEN``),
        where aiomqtt's own clean disconnect would cancel it and leave ``ONLINE``."""
        _log.error("%s: the bridge ends on an error; the last will tells the fleet", self.topic)
        try:
            internals = client_internals(self.client)
        except TypeError:
            internals = None
        if internals is not None:
            inner, disconnected = internals.paho, internals.disconnected
            reason = ReasonCode(PacketTypes.DISCONNECT, identifier=_DISCONNECT_WITH_WILL)
            with contextlib.suppress(Exception):
                if inner.disconnect(reasoncode=reason) == paho.MQTT_ERR_SUCCESS:
                    # aiomqtt's own future: waited for, never cancelled (aiomqtt reads
                    # it on leaving the client).
                    await asyncio.wait((disconnected,), timeout=2.0)
                    if disconnected.done() and not disconnected.cancelled():
                        disconnected.exception()  # retrieved: it is expected
                    return
        await self._out.bounded_state("CONNECTIONBROKEN")  # aiomqtt changed

    async def _stop_robot(self) -> None:
        if self.read_only:
            return  # a viewer never writes to the device, not even a zero
        with contextlib.suppress(ChassisError):
            self._in.source().stop()  # whoever drives: the bridge's end stops the robot


def _first_error(group: BaseExceptionGroup[BaseException]) -> BaseException:
    """The error a task group ended on: its first (a bridge's tasks fail one at a time;
    the others are then cancelled, which is no error)."""
    first = group.exceptions[0]
    return _first_error(first) if isinstance(first, BaseExceptionGroup) else first
