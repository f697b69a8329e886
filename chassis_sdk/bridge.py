"""Robots on an MQTT broker: :class:`MqttBridge` puts one device on a broker the user
already runs, with the deadman kept end to end.

Topics (``{p}`` the prefix, ``{id}`` the robot id; payloads JSON, SI units, field names
as in the Python types):

==============================  ====  ========  ==========================================
topic                           dir   retained  payload
==============================  ====  ========  ==========================================
``{p}/{id}/connection``         out   yes       ``{"state": "ONLINE" | "OFFLINE" |
                                                "CONNECTIONBROKEN", "timestamp": ...}``
``{p}/{id}/link``               out   yes       ``{"state": "connected" | "stale" | ...}``
``{p}/{id}/info``               out   yes       the device's identity
``{p}/{id}/telemetry/{stream}`` out   no        the latest message, at most ``rate``/s
``{p}/{id}/events``             out   no        each ``RobotEvent`` (QoS 1)
``{p}/{id}/cmd/velocity``       in    never     ``{"linear": m/s, "angular": rad/s}``
``{p}/{id}/cmd/stop``           in    never     anything: zero now
``{p}/{id}/cmd/estop``          in    never     ``{"engaged": true | false}``
``{p}/{id}/errors``             out   no        each rejected command and why
``{p}/{id}/request/{name}``     in    never     MQTT 5 request/response: ``get_*``, diagnose
==============================  ====  ========  ==========================================

Why it is shaped this way
-------------------------
A command must never move the robot late. Commands are QoS 0 on a clean session (a
broker keeps nothing for a bridge that is away), a retained or expired command is
refused, and each velocity command is one fresh command under the SDK's deadman
(``command_timeout``): a dashboard that dies, or a Wi-Fi drop, stops the robot within
half a second. Losing the broker writes zero at once, and nothing moves the robot
again but a new command after the bridge is back. The connection topic follows VDA
5050: ``ONLINE`` while bridged, ``OFFLINE`` after a clean stop, and the broker
publishes the last will ``CONNECTIONBROKEN`` when the bridge vanishes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any, cast

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from .core.device import Device
from .core.plain import jsonable, plain
from .core.simulator import next_slot
from .core.validation import check_real
from .devices import DeviceProfile, profile
from .errors import ChassisError

__all__ = ["MqttBridge", "connection_will"]

_log = logging.getLogger("chassis_sdk.bridge")


def _now() -> float:
    return time.time()


def _state(state: str) -> bytes:
    return json.dumps({"state": state, "timestamp": _now()}).encode()


def connection_will(robot_id: str, prefix: str = "robots") -> aiomqtt.Will:
    """The last will a bridge's client must be made with: the broker publishes
    ``CONNECTIONBROKEN`` (retained) on ``{prefix}/{robot_id}/connection`` if the bridge
    vanishes without a clean stop. One client per bridge, since a will is per
    connection."""
    return aiomqtt.Will(
        f"{prefix}/{robot_id}/connection", _state("CONNECTIONBROKEN"), qos=1, retain=True
    )


class CommandError(ValueError):
    """A command or request that is refused, and why (published on ``errors``)."""


def _number(payload: dict[str, Any], key: str) -> float:
    try:
        return check_real(payload.get(key), repr(key))
    except ValueError as exc:
        raise CommandError(str(exc)) from None


def _json_object(raw: bytes | bytearray) -> dict[str, Any]:
    try:
        payload = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise CommandError("the payload is not JSON") from None
    if not isinstance(payload, dict):
        raise CommandError("the payload is not a JSON object")
    return payload


class MqttBridge:
    """One device on an MQTT broker.

    Args:
        device: A connected (or connecting) device; the bridge never closes it.
        client: An ``aiomqtt.Client``, not yet entered, made with
            ``will=connection_will(robot_id, prefix)``, MQTT 5
            (``protocol=aiomqtt.ProtocolVersion.V5``) for request/response, and a clean
            start: the bridge enters it in :meth:`run`.
        robot_id: The robot's name under the prefix (letters, digits, ``-``, ``_``).
        prefix: The first topic level.
        rate: Most telemetry messages per stream per second (the latest, never a
            backlog).
        read_only: Never subscribe to commands (requests are still answered).

    Raises:
        ValueError: A bad robot id, prefix or rate.
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
    ) -> None:
        for name, value in (("robot_id", robot_id), ("prefix", prefix)):
            if not value or not all(c.isalnum() or c in "-_" for c in value):
                raise ValueError(f"{name} must be letters, digits, '-' or '_', got {value!r}")
        rate = check_real(rate, "rate", low=0, low_open=True, high=100, unit="per second")
        self.device = device
        self.client = client
        self.robot_id = robot_id
        self.prefix = prefix
        self.rate = float(rate)
        self.read_only = read_only
        self.topic = f"{prefix}/{robot_id}"
        self.profile: DeviceProfile = profile(device.kind)
        #: Commands refused so far (each also published on ``errors``).
        self.rejected = 0

    async def run(self) -> None:
        """Bridge until cancelled (then publish ``OFFLINE``) or the broker is lost.

        The device is stopped (zero velocity) whenever this returns or raises.

        Raises:
            aiomqtt.MqttError: The broker connection failed or was lost; the robot was
                stopped first. Call :meth:`run` again with a new client to resume.
        """
        # Every await of this task is asyncio.wait (never aiomqtt's own calls, which
        # use asyncio.wait_for: before Python 3.12 it can lose a cancellation), so a
        # cancellation always reaches it; the workers are cancelled until they are done.
        try:
            async with self.client:
                workers = [asyncio.create_task(self._start(), name=f"bridge start:{self.topic}")]
                try:  # from here on, a clean stop (cancellation) says OFFLINE
                    await self._until_failure(workers)
                    workers += [
                        asyncio.create_task(work, name=f"bridge {name}:{self.topic}")
                        for name, work in self._loops()
                    ]
                    await self._until_failure(workers)
                except asyncio.CancelledError:
                    await _cancel_all(workers)
                    await self._offline()
                    raise
                except BaseException:
                    await _cancel_all(workers)
                    raise
        except aiomqtt.MqttError as exc:
            _log.warning("%s: broker lost (%s); the robot is stopped", self.topic, exc)
            raise
        finally:
            await self._stop_robot()

    async def _start(self) -> None:
        await self._publish("connection", _state("ONLINE"), qos=1, retain=True)
        await self._publish_info()
        await self._subscribe()

    def _loops(self) -> list[tuple[str, Coroutine[Any, Any, None]]]:
        loops = [("commands", self._commands()), ("link", self._link()), ("events", self._events())]
        return loops + [(stream, self._telemetry(stream)) for stream in self.profile.streams]

    @staticmethod
    async def _until_failure(workers: list[asyncio.Task[None]]) -> None:
        """Wait until every worker is done, or one fails (its error is raised)."""
        done, _ = await asyncio.wait(workers, return_when=asyncio.FIRST_EXCEPTION)
        for task in done:
            if not task.cancelled() and task.exception() is not None:
                raise cast(BaseException, task.exception())

    async def _offline(self) -> None:
        """Say ``OFFLINE`` (a clean stop), bounded: a broker that does not acknowledge
        within two seconds does not hold the stop up (its last will then tells)."""
        publish = asyncio.ensure_future(
            self._publish("connection", _state("OFFLINE"), qos=1, retain=True)
        )
        # asyncio.wait, unlike wait_for, works in a task that is being cancelled.
        done, _ = await asyncio.wait((publish,), timeout=2.0)
        if not done:
            publish.cancel()
        elif publish.exception() is not None:
            _log.info("%s: could not say OFFLINE: %r", self.topic, publish.exception())

    async def _stop_robot(self) -> None:
        with contextlib.suppress(ChassisError):
            await self.device.stop()

    async def _publish(
        self,
        sub: str,
        payload: bytes,
        *,
        qos: int = 0,
        retain: bool = False,
        properties: Properties | None = None,
    ) -> None:
        await self.client.publish(
            f"{self.topic}/{sub}", payload, qos=qos, retain=retain, properties=properties
        )

    async def _publish_info(self) -> None:
        info: dict[str, Any] = {
            "device": self.profile.name,
            "summary": self.profile.summary,
            "port": self.device.port,
            "features": dict(self.profile.features),
        }
        for name in self.profile.identity:
            try:
                value = await getattr(self.device, name)()
            except ChassisError as exc:
                value = {"error": str(exc)}
            info[name.removeprefix("get_")] = plain(value)
        await self._publish("info", json.dumps(info).encode(), qos=1, retain=True)

    async def _subscribe(self) -> None:
        # QoS 0 and a clean session: a command is never kept for later.
        if not self.read_only:
            await self.client.subscribe(f"{self.topic}/cmd/+", qos=0)
        await self.client.subscribe(f"{self.topic}/request/+", qos=0)

    # --- out ---------------------------------------------------------------------------

    async def _telemetry(self, stream: str) -> None:
        latest: list[Any] = []

        async def follow() -> None:
            async for message in getattr(self.device, stream)():
                latest[:] = [message]

        follower = asyncio.create_task(follow())
        try:
            period = 1.0 / self.rate
            loop = asyncio.get_running_loop()
            due = loop.time()
            while True:
                # An absolute schedule: publishing takes time, and must not slow the rate.
                due = next_slot(due, period, loop.time())
                await asyncio.sleep(due - loop.time())
                if latest:
                    message = latest.pop()
                    payload = json.dumps({"type": type(message).__name__, **jsonable(message)})
                    await self._publish(f"telemetry/{stream}", payload.encode())
        finally:
            follower.cancel()

    async def _link(self) -> None:
        await self._publish("link", _state(self.device.connection_state.value), qos=1, retain=True)
        async for state in self.device.connection_states():
            await self._publish("link", _state(state.value), qos=1, retain=True)

    async def _events(self) -> None:
        async for event in self.device.events():
            payload = {**jsonable(event), "kind": event.kind.value}
            await self._publish("events", json.dumps(payload).encode(), qos=1)

    # --- in ----------------------------------------------------------------------------

    async def _commands(self) -> None:
        async for message in self.client.messages:
            parts = str(message.topic).split("/")
            try:
                if len(parts) == 4 and parts[2] == "request":
                    await self._request(parts[3], message)
                elif len(parts) == 4 and parts[2] == "cmd" and not self.read_only:
                    await self._command(parts[3], message)
            except CommandError as exc:
                await self._reject(str(message.topic), str(exc))
            except ChassisError as exc:
                await self._reject(str(message.topic), f"the device refused it: {exc}")

    async def _reject(self, topic: str, why: str) -> None:
        self.rejected += 1
        _log.info("%s: rejected %s: %s", self.topic, topic, why)
        payload = {"topic": topic, "error": why, "timestamp": _now()}
        await self._publish("errors", json.dumps(payload).encode(), qos=1)

    async def _command(self, name: str, message: aiomqtt.Message) -> None:
        if message.retain:
            raise CommandError("a retained command is never acted on (it would be stale)")
        raw = message.payload if isinstance(message.payload, bytes | bytearray) else b""
        handlers: dict[str, Callable[[bytes | bytearray], Awaitable[None]]] = {
            "velocity": self._velocity,
            "stop": lambda raw: self.device.stop(),
            "estop": self._estop,
        }
        handler = handlers.get(name)
        if handler is None:
            raise CommandError(f"unknown command {name!r}: velocity, stop or estop")
        await handler(raw)

    async def _velocity(self, raw: bytes | bytearray) -> None:
        payload = _json_object(raw)
        linear, angular = _number(payload, "linear"), _number(payload, "angular")
        try:
            # One fresh command under the deadman: it holds command_timeout, no longer.
            await self.device.set_velocity(linear, angular)
        except ValueError as exc:
            raise CommandError(str(exc)) from None

    async def _estop(self, raw: bytes | bytearray) -> None:
        engaged = _json_object(raw).get("engaged")
        if not isinstance(engaged, bool):
            raise CommandError(f"'engaged' must be true or false, got {engaged!r}")
        device: Any = self.device
        if not hasattr(device, "emergency_stop"):
            await self.device.stop()
            raise CommandError(f"a {self.profile.name} has no e-stop; it was stopped")
        await (device.emergency_stop() if engaged else device.release_emergency_stop())

    async def _request(self, name: str, message: aiomqtt.Message) -> None:
        props = message.properties
        response = getattr(props, "ResponseTopic", None) if props is not None else None
        if not response:
            raise CommandError("a request needs an MQTT 5 response topic")
        reply = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        correlation = getattr(props, "CorrelationData", None)
        if correlation is not None:
            reply.CorrelationData = correlation
        if name not in self.profile.requests:
            body: dict[str, Any] = {
                "error": f"unknown request {name!r}; known: {', '.join(self.profile.requests)}"
            }
        else:
            try:
                body = {"result": plain(await getattr(self.device, name)())}
            except ChassisError as exc:
                body = {"error": str(exc)}
        await self.client.publish(response, json.dumps(body).encode(), properties=reply)


async def _cancel_all(tasks: list[asyncio.Task[None]]) -> None:
    """Cancel ``tasks`` until every one is done: a cancellation that a library loses
    (asyncio.wait_for before Python 3.12) is asked again."""
    for _ in range(20):
        pending = [t for t in tasks if not t.done()]
        if not pending:
            return
        for task in pending:
            task.cancel()
        await asyncio.wait(pending, timeout=0.5)
    _log.error(
        "bridge tasks ignore cancellation: %s", [t.get_name() for t in tasks if not t.done()]
    )
