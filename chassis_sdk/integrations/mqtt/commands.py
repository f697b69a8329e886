"""A bridge's command side: what it does with the messages it takes in.

Each message is sorted as paho hands it over (`Commands.sort`, the
`CommandInbox`'s ``sort``), in bounded
work, before anything waits: junk, a retained command, a stale one, an unknown topic
is refused there and then (counted, reported on ``errors``), never queued; stops and
e-stops take their lane (and cancel the velocity command before them), a velocity
command the one slot, a request the short queue its workers serve. Then
`Commands.consume` acts on the commands in the inbox's order, and
`Commands.answer_requests` answers the requests (MQTT 5 request/response), so a
slow request never holds a command up. Nothing is acted on before the bridge owns the
robot id, nor after another bridge took it over
(`Ownership`).

Velocity commands and stops go through the bridge's one source in the device's motion
core (``device.motion.source("mqtt robots/r1", kind="mqtt")``): each accepted velocity
command is offered to it, with its age (from its ``timestamp``, or for one without, the
least age the bridge's probe of the broker -> bridge path shows), and the core paces
the writes (the newest wins), holds each command for the deadman from when it was
given, and refuses it while motion is blocked or another source drives; its refusal is
reported on ``errors`` like any other. A command without a ``timestamp`` that arrives
while that probe shows the path held up for longer than the deadman is refused as held
up (`PathProbe`; the publishing side sends the probes).

`Commands` is `MqttBridge`'s collaborator
for this: it is given a `CommandContext` (the bridge's client, topic, device, profile,
owner and options: ``read_only``, ``require_timestamp``, ``max_age``, ``deadman``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import time
from typing import TYPE_CHECKING, Any

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from ...core.plain import plain
from ...errors import ChassisError
from ..inbound import (
    TIMESTAMP_SKEW,
    CommandError,
    check_fresh,
    command_number,
    command_object,
    command_time,
)
from .context import CommandContext
from .goals import GOALS, RemoteGoals
from .inbox import Lanes, PathProbe
from .ownership import Ownership
from .publish import Publisher, epoch_now

if TYPE_CHECKING:
    from ...core.motion import MotionSource

__all__ = ["REQUEST_WORKERS", "Commands"]

#: Requests pending; more are refused (a request is answered or refused, never late).
_REQUESTS_MAX = 16
#: Workers answering requests (each may wait for the device for a few seconds).
REQUEST_WORKERS = 2
#: Seconds between two probes of the broker -> bridge path (`Publisher.run` sends them).
PROBE_PERIOD = 0.15


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
_ROBOT_TREES = (
    "connection",
    "cmd",
    "request",
    "errors",
    "info",
    "link",
    "telemetry",
    "events",
    "probe",
)
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


def _topic(message: aiomqtt.Message) -> str:
    with contextlib.suppress(Exception):
        return str(message.topic.value)[:200]
    return "?"


class Commands:
    """A bridge's command side: sorting what comes in, acting on the commands and
    answering the requests (see the module docstring)."""

    def __init__(
        self, context: CommandContext, publisher: Publisher, ownership: Ownership, lanes: Lanes
    ) -> None:
        self._ctx = context
        self._out = publisher
        self._ownership = ownership
        self._lanes = lanes
        self._base = f"{context.topic}/"
        #: Commands never acted on for ownership: routed before this bridge's ONLINE,
        #: or after another bridge took over.
        self.dropped = 0
        #: Velocity commands without a timestamp refused as held up on their way.
        self.held_up = 0
        #: The broker -> bridge path, probed: `sort` tells it when a probe is back
        #: (`Publisher.run` sends them).
        self.path = PathProbe(PROBE_PERIOD, keep=context.deadman + 1.0)
        self._source: MotionSource | None = None
        #: The goals (``request/move|turn|goto``, ``cmd/cancel``).
        self.goals = RemoteGoals(context)
        # asyncio's event, not anyio's: this wake-up is cleared by the loop it wakes
        # (anyio's cannot be).
        self._request_ready = asyncio.Event()

    def source(self) -> MotionSource:
        """The bridge's source in the device's motion core (made on first use)."""
        source = self._source
        if source is None or source.source.closed:
            ctx = self._ctx
            source = ctx.device.motion.source(f"mqtt {ctx.topic}", kind="mqtt")
            self._source = source
        return source

    def close(self) -> None:
        """Remove the bridge's source (the robot stops if it was driving) and cancel
        its goal."""
        self.goals.close()
        if self._source is not None:
            self._source.close()

    async def subscribe(self) -> None:
        """Subscribe to the commands (unless read-only) and the requests."""
        ctx = self._ctx
        # QoS 0 and a clean session: a command is never kept for later. Retain As
        # Published (MQTT 5 §3.8.3.1): a live retained command keeps RETAIN 1, so it is
        # refused like a stored one (without it the broker clears the flag).
        if not ctx.read_only:
            await ctx.client.subscribe(
                f"{ctx.topic}/cmd/+", options=SubscribeOptions(qos=0, retainAsPublished=True)
            )
            await ctx.client.subscribe(
                f"{ctx.topic}/probe", options=SubscribeOptions(qos=0, retainAsPublished=True)
            )
        await ctx.client.subscribe(f"{ctx.topic}/request/+", qos=0)

    def _probe_back(self, message: aiomqtt.Message) -> None:
        """A message on the probe topic, as paho hands it over: the path's news if it
        is one of this bridge's probes; refused if retained (nobody's probe)."""
        if message.retain:
            raise CommandError("a retained message on the probe topic is nobody's probe")
        payload = command_object(message.payload)
        number = payload.get("probe")
        if payload.get("owner") == self._ctx.owner and type(number) is int:
            self.path.back(number)

    def sort(self, message: aiomqtt.Message) -> bool:
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
        if sub == "probe":
            self._probe_back(message)
            return False
        kind, _, name = sub.partition("/")
        lanes = self._lanes
        if kind == "request" and name and "/" not in name:
            if not self._ownership.echoed.is_set():
                self.dropped += 1  # as a command: the previous owner answers it
                return False
            if len(lanes.requests) >= _REQUESTS_MAX:
                raise CommandError(f"{_REQUESTS_MAX} requests are pending already")
            lanes.requests.append(message)
            self._request_ready.set()
            return False
        if kind != "cmd" or self._ctx.read_only or "/" in name:
            return False
        if self._ownership.displaced_by is not None:
            self.dropped += 1  # another bridge owns the robot id now
            return False
        if message.retain:
            raise CommandError("a retained command is never acted on (it would be stale)")
        if name == "cancel":  # as a stop: at once, in the read callback
            if not self.goals.cancel():
                raise CommandError("cancel: no goal is running")
            return False
        since, neutral = None, False
        if name == "velocity":
            # Junk and stale ones never take the slot; nor does one held up on its way.
            linear, angular, stamp = self._velocity_of(message)
            since, neutral = self._given_by(stamp), linear == 0 and angular == 0
            lane = "velocity"
        elif name == "stop":
            lane = "stop"
        elif name == "estop":
            lane = "engage" if self._estop_of(message) else "release"
        else:
            raise CommandError(f"unknown command {name[:40]!r}: velocity, stop, estop or cancel")
        if not self._ownership.echoed.is_set():
            # Routed before our ONLINE, in the broker's order: it may have reached the
            # bridge that owned the robot id until then. Those after it are held until
            # the claim is settled (the consumer starts only then; a lost claim clears
            # them), so the robot is commanded from the moment ONLINE is seen.
            self.dropped += 1
            return False
        if lane == "velocity":
            return lanes.put_velocity(message, since, neutral=neutral)
        return lanes.put_urgent(lane, message)

    def _given_by(self, stamp: float | None) -> float | None:
        """When a velocity command arriving now was given at the latest
        (``time.monotonic()``), by the probe of the path: ``None`` for a stamped one
        (its stamp says).

        Raises:
            CommandError: It has no timestamp, and the probe shows the path held it
                up for longer than the deadman.
        """
        if stamp is not None:
            return None
        held = self.path.held()
        deadman = self._ctx.deadman
        if held > deadman:
            self.held_up += 1
            raise CommandError(
                f"held up: the broker -> bridge path has held what it carries for {held:.3f} s "
                f"(by the bridge's probe), more than the {deadman:g} s deadman, and the command "
                "has no 'timestamp' to tell its age"
            )
        return time.monotonic() - held

    def _check_time(self, payload: dict[str, Any]) -> float | None:
        """The command's timestamp (epoch seconds), checked fresh; ``None`` if none."""
        stamp = payload.get("timestamp")
        if stamp is None:
            if self._ctx.require_timestamp:
                raise CommandError("the command has no 'timestamp', and this bridge requires one")
            return None
        seconds = command_time(stamp)
        check_fresh(seconds, self._ctx.max_age)
        return seconds

    def _velocity_of(self, message: aiomqtt.Message) -> tuple[float, float, float | None]:
        payload = command_object(message.payload)
        linear, angular = (
            command_number(payload, "linear", repr("linear")),
            command_number(payload, "angular", repr("angular")),
        )
        return linear, angular, self._check_time(payload)

    def _age(self, stamp: float | None, since: float) -> float:
        """How old a velocity command is, for the core's deadman: from its stamp (less
        the skew allowed to the sender's clock), else from when the probe of the path
        shows it was given at the latest (``since``, ``time.monotonic()``)."""
        if stamp is None:
            return max(0.0, time.monotonic() - since)
        return max(0.0, epoch_now() - stamp - TIMESTAMP_SKEW)

    def _estop_of(self, message: aiomqtt.Message) -> bool:
        payload = command_object(message.payload)
        engaged = payload.get("engaged")
        if not isinstance(engaged, bool):
            raise CommandError(f"'engaged' must be true or false, got {str(engaged)[:40]!r}")
        if not engaged:
            self._check_time(payload)  # a release is as late-sensitive as a velocity
        return engaged

    async def consume(self) -> None:
        """Act on the commands as the inbox serves them: stops and e-stops first, then
        the newest velocity command (the motion core paces what is written)."""
        async for message in self._ctx.client.messages:
            try:
                await self._act(message)
            except Exception as exc:  # any failure is this message's refusal, no more
                self._out.refuse(_topic(message), _why(exc))

    async def _act(self, message: aiomqtt.Message) -> None:
        if self._ownership.displaced_by is not None:
            self.dropped += 1
            return
        ctx = self._ctx
        name = message.topic.value.rpartition("/")[2]
        if name == "velocity":
            lanes = self._lanes
            if not lanes.current(message):
                # A stop or e-stop was sorted after it (while it was out of its slot):
                # it must never act after that stop.
                lanes.superseded += 1
                return
            # Checked again: it may have waited (a little) for a stop to be served.
            linear, angular, stamp = self._velocity_of(message)
            # One command under the deadman, counted from when it was given: its stamp
            # (plus the skew), or the least age the probe of the path showed. Nothing
            # awaits between the epoch's check and the offer, so no stop comes between.
            timeout = ctx.device.command_timeout
            duration = None if timeout is not None else ctx.deadman
            source = self.source()
            if lanes.neutral_passed:
                # The sender gave a zero that a newer command superseded in the slot:
                # it still counts as its neutral (after a block, the core wants one).
                lanes.neutral_passed = False
                if not source.driving:
                    source.set_velocity(0.0, 0.0)
            refusal = source.set_velocity(
                linear, angular, duration=duration, age=self._age(stamp, lanes.since(message))
            )
            if refusal is not None:
                raise CommandError(f"velocity refused: {refusal.detail}")
        elif name == "stop":
            self.source().stop()
        elif name == "estop":
            engaged = self._estop_of(message)
            device: Any = ctx.device
            if not hasattr(device, "emergency_stop"):
                self.source().stop()
                raise CommandError(f"a {ctx.profile.name} has no e-stop; it was stopped")
            await (device.emergency_stop() if engaged else device.release_emergency_stop())

    async def answer_requests(self) -> None:
        """Answer the requests as they come (one of the bridge's request workers)."""
        requests = self._lanes.requests
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
        ctx = self._ctx
        name = message.topic.value.rpartition("/")[2]
        props = message.properties
        response = _check_response_topic(getattr(props, "ResponseTopic", None), ctx.prefix)
        correlation = _check_correlation(getattr(props, "CorrelationData", None))
        reply = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        if correlation is not None:
            reply.CorrelationData = correlation
        known = ctx.profile.remote.requests
        if name in GOALS:
            if ctx.read_only:
                raise CommandError(f"{name}: this bridge is read-only")
            if self._ownership.displaced_by is not None:
                self.goals.close()
                raise CommandError(f"{name}: another bridge owns this robot id now")
            args = self.goals.parse(name, message.payload)

            async def answer(body: dict[str, Any]) -> None:
                await ctx.client.publish(response, json.dumps(body).encode(), properties=reply)

            self.goals.start(name, args, answer)
            return
        if name not in known:
            body: dict[str, Any] = {
                "error": f"unknown request {name[:40]!r}; known: {', '.join((*known, *GOALS))}"
            }
        else:
            try:
                body = {"result": plain(await getattr(ctx.device, name)())}
            except ChassisError as exc:
                body = {"error": str(exc)}
        await ctx.client.publish(response, json.dumps(body).encode(), properties=reply)
