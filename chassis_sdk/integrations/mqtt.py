"""Robots on an MQTT broker: :class:`MqttBridge` puts one device on a broker the user
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
==============================  ====  ========  ==========================================

Why it is shaped this way
-------------------------
A command must never move the robot late. Commands are QoS 0 on a clean session (a
broker keeps nothing for a bridge that is away), a retained or stale command is
refused (one whose MQTT 5 message expiry has passed the broker never delivers), and
each velocity command is one command under the SDK's deadman
(``command_timeout``, counted from its ``timestamp`` when it has one): a dashboard
that dies, or a Wi-Fi drop, stops the robot within half a second. Losing the broker
writes zero at once, and nothing moves the robot again but a new command after the
bridge is back. The connection topic follows VDA 5050: ``ONLINE`` while bridged,
``OFFLINE`` after a clean stop, and the broker publishes the last will
``CONNECTIONBROKEN`` when the bridge vanishes, or ends on an error of its own (it then
disconnects with reason 0x04, "with Will Message").

Messages come from a network the robot does not control, so nothing about one may
end the bridge, and no rate of them may delay a stop. Both are settled where a
message enters: the client's incoming queue is a :class:`CommandInbox`, and each
message is sorted as paho hands it over, in bounded work, before anything waits:

- junk, a retained command, a stale one, an unknown topic: refused there and then
  (counted; reported on ``errors`` by a reporter of its own, at most once a second),
  never queued;
- ``cmd/stop`` and ``cmd/estop``: a lane of their own, served first, and they cancel
  any velocity command that came before them; they are never dropped (a run of them
  collapses to what it means: engaged if any engaged, stopped, released last if so);
- ``cmd/velocity``: one slot, the newest valid command: velocity is state, not a
  queue, so a flood leaves at most one pending command and the deadman runs from the
  last one the sender published;
- ``request/...``: a short bounded queue served by two workers of their own, so a slow
  device request never holds a command up.

Memory is therefore bounded whatever arrives (a lane holds at most a few messages).

Two bridges must never drive for one robot id. Each bridge has an owner id (host,
process, random) that it puts in its ``connection`` payload; before it acts on any
command it publishes ``ONLINE`` and reads the topic back (commands routed before its
``ONLINE`` are dropped: they may have reached the previous owner; those after it are
held): if the message before its own says another owner is ``ONLINE``, it drops what
it held, puts that message back and refuses to start (:class:`RobotIdTaken`), unless
it was told to take over. A running bridge that sees a
take-over stops taking commands at once (in the order the broker delivered them, so
no command routed to the new bridge reaches the old one), stops its robot and ends
with :class:`RobotIdTaken`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import math
import re
from collections.abc import Callable, Coroutine
from typing import Any

import aiomqtt
import anyio
from anyio.abc import TaskGroup
from paho.mqtt import client as paho
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from paho.mqtt.subscribeoptions import SubscribeOptions

from ..core.device import Device
from ..core.plain import plain
from ..core.validation import check_real
from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from .inbound import (
    TIMESTAMP_SKEW,
    check_fresh,
    command_object,
    command_time,
)
from .inbound import CommandError as CommandError  # re-exported: it was defined here
from .mqtt_inbox import CommandInbox, install_inbox
from .mqtt_ownership import Ownership, RobotIdTaken, new_owner
from .mqtt_publish import Publisher, connection_will, epoch_now

__all__ = [
    "CommandError",
    "CommandInbox",
    "MqttBridge",
    "RobotIdTaken",
    "connection_will",
    "new_owner",
]

_log = logging.getLogger("chassis_sdk.integrations.mqtt")

#: Requests pending; more are refused (a request is answered or refused, never late).
_REQUESTS_MAX = 16
#: Least seconds between two velocity commands written (50 a second, the rate of the
#: chassis's telemetry; a joystick sends 10 to 50): the newest in between counts.
_VELOCITY_PERIOD = 0.02
#: Workers answering requests (each may wait for the device for a few seconds).
_REQUEST_WORKERS = 2
#: The disconnect reason that makes the broker publish the last will (MQTT 5 §3.14.2.1).
_DISCONNECT_WITH_WILL = 0x04


def _deadman(device: Device[Any, Any]) -> float:
    """The device's ``command_timeout`` (its deadman), or 0.5 s if it has none."""
    timeout = device.command_timeout
    return 0.5 if timeout is None else float(timeout)


def _number(payload: dict[str, Any], key: str) -> float:
    try:
        return check_real(payload.get(key), repr(key))
    except ValueError as exc:
        raise CommandError(str(exc)) from None


def _why(exc: Exception) -> str:
    """One line saying why a message was refused, whatever went wrong with it."""
    if isinstance(exc, CommandError):
        text = str(exc)
    elif isinstance(exc, ChassisError):
        text = f"the device refused it: {exc}"
    elif isinstance(exc, ValueError):
        text = str(exc)
    else:  # a failure nobody foresaw is still only this message's refusal
        text = f"{type(exc).__name__} while handling it: {exc}"
    return " ".join(text.split())[:300] or type(exc).__name__


#: ``{prefix}/{id}/cmd/...`` and ``{prefix}/{id}/request/...`` of any robot: never a
#: response topic, or a request could command a robot (its own or another).
_COMMAND_TREE = re.compile(r"^[^/]+/[^/]+/(cmd|request)(/|$)")
#: The subtrees of a robot under the bridge's prefix: what a bridge publishes or takes
#: there (a reply must not forge a robot's state, nor command one).
_ROBOT_TREES = ("connection", "cmd", "request", "errors", "info", "link", "telemetry", "events")
#: The longest response topic and correlation data answered (bytes): a reply is small,
#: and a request must not make the bridge publish (or hold) much more than it sent.
_MAX_RESPONSE_TOPIC = 1024
_MAX_CORRELATION = 1024


def _check_response_topic(topic: object, prefix: str = "robots") -> str:
    """A response topic the bridge may publish to (MQTT 5 §3.3.2.3.5, §4.7): at most
    1024 bytes, no wildcard, and never in a robot's subtree under ``prefix``."""
    if not isinstance(topic, str) or not topic:
        raise CommandError("a request needs an MQTT 5 response topic")
    if "#" in topic or "+" in topic:
        raise CommandError("the response topic has a wildcard ('#' or '+'; MQTT 5 §3.3.2.3.5)")
    size = len(topic.encode(errors="replace"))
    if size > _MAX_RESPONSE_TOPIC:
        raise CommandError(
            f"the response topic is {size} bytes; at most {_MAX_RESPONSE_TOPIC} are answered"
        )
    if "\x00" in topic or topic.startswith("$"):
        raise CommandError("the response topic is not a topic a client may publish to")
    if _COMMAND_TREE.match(topic):
        raise CommandError("the response topic is a command or request topic")
    levels = topic.split("/")
    if len(levels) >= 3 and levels[0] == prefix and levels[2] in _ROBOT_TREES:
        raise CommandError(
            f"the response topic is in a robot's {levels[2]!r} subtree under {prefix!r}/"
        )
    return topic


def _check_correlation(data: object) -> bytes | None:
    """The correlation data to send back, at most 1024 bytes (``None``: there is none)."""
    if data is None:
        return None
    if not isinstance(data, bytes | bytearray):
        raise CommandError(f"the correlation data is {type(data).__name__}, not bytes")
    if len(data) > _MAX_CORRELATION:
        raise CommandError(
            f"the correlation data is {len(data)} bytes; at most {_MAX_CORRELATION} are answered"
        )
    return bytes(data)


class MqttBridge:
    """One device on an MQTT broker.

    Args:
        device: A connected (or connecting) device; the bridge never closes it.
        client: An ``aiomqtt.Client``, not yet entered, made with
            ``will=connection_will(robot_id, prefix, owner)``, MQTT 5
            (``protocol=aiomqtt.ProtocolVersion.V5``), a clean start, a client id of
            its own (two bridges must never share one) and ``queue_type=CommandInbox``:
            the bridge enters it in :meth:`run`.
        robot_id: The robot's name under the prefix (letters, digits, ``-``, ``_``).
        prefix: The first topic level.
        rate: Most telemetry messages per stream per second (the latest, never a
            backlog).
        read_only: Never subscribe to commands (requests are still answered).
        owner: This bridge's owner id, published in ``connection`` (default: a new
            :func:`new_owner`). Keep one across reconnects of one service.
        take_over: Start even if another bridge is ``ONLINE`` for this robot id; that
            bridge stops its robot and ends.
        require_timestamp: Refuse velocity commands and e-stop releases without a
            ``timestamp``.
        max_age: The oldest a command may be, by its ``timestamp`` (seconds; plus
            :data:`chassis_sdk.integrations.inbound.TIMESTAMP_SKEW`); default the device's
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
        for name, value in (("robot_id", robot_id), ("prefix", prefix)):
            if not value or not all(c.isalnum() or c in "-_" for c in value):
                raise ValueError(f"{name} must be letters, digits, '-' or '_', got {value!r}")
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
        self._base = f"{self.topic}/"
        self.profile: DeviceProfile = profile(device.kind)
        #: Commands never acted on for ownership: routed before this bridge's ONLINE,
        #: or after another bridge took over.
        self.dropped = 0
        # asyncio's events, not anyio's: these wake-ups are cleared by the loop they
        # wake (anyio's cannot be), and the claim must go on the moment the echo is
        # in (anyio's wait() yields once even when the event is set already, and a
        # stop in that moment would find the bridge not yet online: no OFFLINE).
        self._request_ready = asyncio.Event()
        self._urgent = asyncio.Event()
        self._out = Publisher(self, float(report_interval))
        self._inbox = install_inbox(client)
        self._ownership = Ownership(self, self._out, self._inbox.lanes)
        self._inbox.sort = self._sort

    @property
    def rejected(self) -> int:
        """Messages refused so far (each counted; reported on ``errors``, summarised)."""
        return self._out.refusals.total

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

    async def run(self) -> None:
        """Bridge until cancelled (then publish ``OFFLINE``) or the broker is lost.

        The device is stopped (zero velocity) whenever this returns or raises, unless
        the bridge is ``read_only`` (a viewer never writes to the device). If it
        ends on an error of its own, it disconnects so that the broker publishes the
        last will (``CONNECTIONBROKEN``).

        Raises:
            aiomqtt.MqttError: The broker connection failed or was lost; the robot was
                stopped first. Call :meth:`run` again with a new client to resume.
            RobotIdTaken: Another bridge is ``ONLINE`` for this robot id (this one
                never took a command), or it took over (this one stopped its robot).
        """
        # The bridge's work runs in a task group, and this task awaits nothing else
        # while it runs: leaving the group cancels the workers until they are done,
        # however often a library loses a cancellation (aiomqtt's calls use
        # asyncio.wait_for, which can before Python 3.12).
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
        await self._ownership.claim(self._subscribe_commands)
        await self._out.info()

    def _loops(self) -> list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]]:
        loops: list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]] = [
            ("commands", self._commands),
            ("owner", self._ownership.watch),
            ("errors", self._out.reporter),
            ("link", self._out.link_states),
            ("events", self._events),
        ]
        loops += [(f"requests {n}", self._requests) for n in range(_REQUEST_WORKERS)]
        return loops + [
            (stream, functools.partial(self._out.telemetry, stream))
            for stream in self.profile.remote.streams
        ]

    async def _events(self) -> None:
        # The events loop, by name on the bridge (where a test puts a failing one).
        await self._out.events()

    async def _fail_loudly(self) -> None:
        """The bridge ends on an error of its own: tell the fleet. A DISCONNECT with
        reason 0x04 makes the broker publish the last will (``CONNECTIONBROKEN``),
        where aiomqtt's own clean disconnect would cancel it and leave ``ONLINE``."""
        _log.error("%s: the bridge ends on an error; the last will tells the fleet", self.topic)
        client: Any = self.client
        inner = getattr(client, "_client", None)
        disconnected = getattr(client, "_disconnected", None)
        if isinstance(inner, paho.Client) and isinstance(disconnected, asyncio.Future):
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
            await self.device.stop()

    async def _subscribe_commands(self) -> None:
        # QoS 0 and a clean session: a command is never kept for later. Retain As
        # Published (MQTT 5 §3.8.3.1): a live retained command keeps RETAIN 1, so it is
        # refused like a stored one (without it the broker clears the flag).
        if not self.read_only:
            await self.client.subscribe(
                f"{self.topic}/cmd/+", options=SubscribeOptions(qos=0, retainAsPublished=True)
            )
        await self.client.subscribe(f"{self.topic}/request/+", qos=0)

    # --- in ----------------------------------------------------------------------------

    def _sort(self, message: aiomqtt.Message) -> bool:
        """Sort one message as it arrives (in paho's read callback): refuse it, act on
        it (the connection topic), or leave it in its lane. Never raises."""
        try:
            return self._sort_one(message)
        except Exception as exc:  # any failure is this message's refusal, no more
            self._out.refuse(_topic(message), _why(exc))
            return False

    def _sort_one(self, message: aiomqtt.Message) -> bool:
        topic = message.topic.value
        if not topic.startswith(self._base):
            return False  # not ours (a wider subscription of the user's)
        sub = topic[len(self._base) :]
        if sub == "connection":
            self._ownership.on_connection(message)
            return False
        kind, _, name = sub.partition("/")
        lanes = self._inbox.lanes
        if kind == "request" and name and "/" not in name:
            if not self._echoed.is_set():
                self.dropped += 1  # as a command: the previous owner answers it
                return False
            if len(lanes.requests) >= _REQUESTS_MAX:
                raise CommandError(f"{_REQUESTS_MAX} requests are pending already")
            lanes.requests.append(message)
            self._request_ready.set()
            return False
        if kind != "cmd" or self.read_only or "/" in name:
            return False
        if self._ownership.displaced_by is not None:
            self.dropped += 1  # another bridge owns the robot id now
            return False
        if message.retain:
            raise CommandError("a retained command is never acted on (it would be stale)")
        if name == "velocity":
            self._velocity_of(message)  # junk and stale ones never take the slot
            lane = "velocity"
        elif name == "stop":
            lane = "stop"
        elif name == "estop":
            lane = "engage" if self._estop_of(message) else "release"
        else:
            raise CommandError(f"unknown command {name[:40]!r}: velocity, stop or estop")
        if not self._echoed.is_set():
            # Routed before our ONLINE, in the broker's order: it may have reached the
            # bridge that owned the robot id until then. Those after it are held until
            # the claim is settled (the consumer starts only then; a lost claim clears
            # them), so the robot is commanded from the moment ONLINE is seen.
            self.dropped += 1
            return False
        if lane == "velocity":
            return lanes.put_velocity(message)
        self._urgent.set()  # a velocity command held for its period gives way
        return lanes.put_urgent(lane, message)

    def _check_time(self, payload: dict[str, Any]) -> float | None:
        """The command's timestamp (epoch seconds), checked fresh; ``None`` if none."""
        stamp = payload.get("timestamp")
        if stamp is None:
            if self.require_timestamp:
                raise CommandError("the command has no 'timestamp', and this bridge requires one")
            return None
        seconds = command_time(stamp)
        check_fresh(seconds, self.max_age)
        return seconds

    def _velocity_of(self, message: aiomqtt.Message) -> tuple[float, float, float | None]:
        payload = command_object(message.payload)
        linear, angular = _number(payload, "linear"), _number(payload, "angular")
        return linear, angular, self._check_time(payload)

    def _hold(self, stamp: float | None) -> float | None:
        """How long a velocity command stamped ``stamp`` may hold from now: until its
        stamp plus the deadman (plus the skew), never longer than the deadman; ``None``
        (the device's own deadman) for a command without a timestamp."""
        if stamp is None:
            return None
        left = stamp + self.deadman + TIMESTAMP_SKEW - epoch_now()
        if left <= 0:
            raise CommandError(
                f"the command is {epoch_now() - stamp:.3f} s old: its {self.deadman:g} s deadman "
                "(plus the skew) ran out before it could act"
            )
        return min(self.deadman, left)

    def _estop_of(self, message: aiomqtt.Message) -> bool:
        payload = command_object(message.payload)
        engaged = payload.get("engaged")
        if not isinstance(engaged, bool):
            raise CommandError(f"'engaged' must be true or false, got {str(engaged)[:40]!r}")
        if not engaged:
            self._check_time(payload)  # a release is as late-sensitive as a velocity
        return engaged

    async def _commands(self) -> None:
        lanes = self._inbox.lanes
        next_velocity = -math.inf
        async for message in self.client.messages:
            try:
                velocity = message.topic.value.endswith("/cmd/velocity")
                wait = next_velocity - anyio.current_time()
                if velocity and wait > 0:
                    # At most one velocity command per period reaches the device, the
                    # newest: the work (and the serial line) stays bounded whatever
                    # the rate. It waits in its slot, where a newer one replaces it
                    # and a stop or e-stop cancels it and is served at once.
                    lanes.put_back(message)  # dropped if a stop came after it
                    self._urgent.clear()
                    if not lanes.urgent:
                        with anyio.move_on_after(wait):
                            await self._urgent.wait()
                    continue
                await self._act(message)
                if velocity:
                    next_velocity = anyio.current_time() + _VELOCITY_PERIOD
            except Exception as exc:  # any failure is this message's refusal, no more
                self._out.refuse(_topic(message), _why(exc))

    async def _act(self, message: aiomqtt.Message) -> None:
        if self._ownership.displaced_by is not None:
            self.dropped += 1
            return
        name = message.topic.value.rpartition("/")[2]
        if name == "velocity":
            if not self._inbox.lanes.current(message):
                # A stop or e-stop was sorted after it (while it was out of its slot):
                # it must never act after that stop.
                self._inbox.lanes.superseded += 1
                return
            # Checked again: it may have waited (a little) for a stop to be served.
            linear, angular, stamp = self._velocity_of(message)
            # One command under the deadman, counted from when it was sent: a stamped
            # command holds until its stamp plus command_timeout, no longer (a newer
            # one replaces it). Nothing awaits between the epoch's check and the write
            # (set_velocity writes before its first await), so no stop comes between.
            await self.device.set_velocity(linear, angular, duration=self._hold(stamp))
        elif name == "stop":
            await self.device.stop()
        elif name == "estop":
            engaged = self._estop_of(message)
            device: Any = self.device
            if not hasattr(device, "emergency_stop"):
                await self.device.stop()
                raise CommandError(f"a {self.profile.name} has no e-stop; it was stopped")
            await (device.emergency_stop() if engaged else device.release_emergency_stop())

    async def _requests(self) -> None:
        requests = self._inbox.lanes.requests
        while True:
            while not requests:
                self._request_ready.clear()
                await self._request_ready.wait()
            message = requests.popleft()
            try:
                await self._request(message)
            except aiomqtt.MqttError:
                raise  # the broker is gone: the bridge ends
            except Exception as exc:  # any failure is this request's refusal, no more
                self._out.refuse(_topic(message), _why(exc))

    async def _request(self, message: aiomqtt.Message) -> None:
        name = message.topic.value.rpartition("/")[2]
        props = message.properties
        response = _check_response_topic(getattr(props, "ResponseTopic", None), self.prefix)
        correlation = _check_correlation(getattr(props, "CorrelationData", None))
        reply = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        if correlation is not None:
            reply.CorrelationData = correlation
        known = self.profile.remote.requests
        if name not in known:
            body: dict[str, Any] = {
                "error": f"unknown request {name[:40]!r}; known: {', '.join(known)}"
            }
        else:
            try:
                body = {"result": plain(await getattr(self.device, name)())}
            except ChassisError as exc:
                body = {"error": str(exc)}
        await self.client.publish(response, json.dumps(body).encode(), properties=reply)


def _topic(message: aiomqtt.Message) -> str:
    with contextlib.suppress(Exception):
        return str(message.topic.value)[:200]
    return "?"


def _first_error(group: BaseExceptionGroup[BaseException]) -> BaseException:
    """The error a task group ended on: its first (a bridge's tasks fail one at a time;
    the others are then cancelled, which is no error)."""
    first = group.exceptions[0]
    return _first_error(first) if isinstance(first, BaseExceptionGroup) else first
