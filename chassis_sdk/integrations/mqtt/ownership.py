"""Who owns a robot id on the broker: a bridge's claim, and what it reads on its
``connection`` topic afterwards.

Two bridges must never drive for one robot id. Each bridge has an owner id
(`new_owner`); before it acts on any command it publishes ``ONLINE`` and reads
the topic back: the broker sends every subscriber a topic's messages in one order, so
the message just before its own is the state it replaced (a retained one, or a racing
bridge's claim). If that says another owner is ``ONLINE``, the bridge puts it back and
refuses to start (`RobotIdTaken`), unless it was told to take over. A running
bridge that sees a take-over stops taking commands at once and ends with
`RobotIdTaken`; anything else published there (a racing bridge's claim, a stale
last will) makes it say ``ONLINE`` again, at most once a second.

`Ownership` is `MqttBridge`'s collaborator
for this: it is given an `OwnershipContext` (the bridge's client, topic, owner and
``take_over``).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import secrets
import socket
import time
from collections.abc import Awaitable, Callable
from typing import Any

import aiomqtt
import anyio
from paho.mqtt.subscribeoptions import SubscribeOptions

from ...errors import ChassisError
from ..inbound import CommandError, command_object
from .context import OwnershipContext
from .inbox import Lanes
from .publish import Publisher, state_payload

__all__ = ["Ownership", "RobotIdTaken", "new_owner"]

#: Seconds to wait for the broker to send a bridge's own ``ONLINE`` back at start.
_ECHO_TIMEOUT = 5.0
#: Least seconds between two re-publications of ``ONLINE`` (another message appeared
#: on the connection topic: a racing bridge's, or a stale last will).
_REASSERT_INTERVAL = 1.0


def new_owner() -> str:
    """A new owner id for a bridge: ``host:pid:random``, unique per bridge, and telling
    an operator where the bridge runs."""
    return f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(3)}"


class RobotIdTaken(ChassisError):
    """Another bridge holds this robot id: this one refused to start, or it was taken
    over and stopped its robot. The message names the other bridge's owner."""


class Ownership:
    """A bridge's claim on its robot id, and its watch on the ``connection`` topic."""

    def __init__(self, context: OwnershipContext, publisher: Publisher, lanes: Lanes) -> None:
        self._ctx = context
        self._out = publisher
        self._lanes = lanes
        #: True once this bridge is the robot id's owner on the broker (it has read its
        #: own ``ONLINE`` back and found no other bridge before it).
        self.online = False
        #: The owner of the bridge that took over, once one did.
        self.displaced_by: str | None = None
        # asyncio's events, not anyio's: these wake-ups are cleared by the loop they
        # wake (anyio's cannot be), and the claim must go on the moment the echo is
        # in (anyio's wait() yields once even when the event is set already, and a
        # stop in that moment would find the bridge not yet online: no OFFLINE).
        #: Set when the broker sent this bridge's own ``ONLINE`` back: commands routed
        #: after it are this bridge's.
        self.echoed = asyncio.Event()
        self._wanted = asyncio.Event()
        self._online_payload = b""
        self._before: tuple[bytes, dict[str, Any]] | None = None
        self._reassert = False

    async def claim(self, subscribe_commands: Callable[[], Awaitable[None]]) -> None:
        """Become the robot id's owner, or raise `RobotIdTaken`.

        The bridge publishes its ``ONLINE`` and reads the topic back: the broker sends
        every subscriber a topic's messages in one order, so the message just before
        our own is the state we replaced (a retained one, or a racing bridge's claim).
        ``subscribe_commands`` subscribes to the commands before the ``ONLINE`` goes.
        """
        ctx = self._ctx
        self._online_payload = state_payload("ONLINE", ctx.owner, take_over=ctx.take_over)
        # Retain As Published (MQTT 5 §3.8.3.1): a bridge publishes its state retained,
        # so a claim or take-over keeps RETAIN 1; a message without it is nobody's.
        await ctx.client.subscribe(
            f"{ctx.topic}/connection",
            options=SubscribeOptions(qos=1, retainAsPublished=True),
        )
        await subscribe_commands()  # held until the claim is settled (see Commands.sort)
        await self._out.publish("connection", self._online_payload, qos=1, retain=True)
        try:
            with anyio.fail_after(_ECHO_TIMEOUT):
                await self.echoed.wait()
        except TimeoutError:
            raise ChassisError(
                f"{ctx.topic}/connection: the broker did not send this bridge's ONLINE "
                f"back within {_ECHO_TIMEOUT:g} s (may its user read that topic? see "
                "docs/mqtt.md, Access control)"
            ) from None
        other = self._other_owner(self._before)
        if other is not None and not ctx.take_over:
            assert self._before is not None
            self._lanes.clear()  # none of them is ours to act on
            raw, state = self._before
            # Ours replaced theirs as the retained state: put it back before leaving.
            await self._out.publish("connection", raw, qos=1, retain=True)
            since = state.get("timestamp")
            when = f" since {_clock(since)}" if isinstance(since, int | float) else ""
            raise RobotIdTaken(
                f"{ctx.topic} is already bridged by {other} (ONLINE{when}); stop that "
                "bridge first, or start this one with --take-over (take_over=True)"
            )
        self.online = True

    def _other_owner(self, seen: tuple[bytes, dict[str, Any]] | None) -> str | None:
        """The owner of ``seen`` if it says another bridge is ONLINE."""
        if seen is None or seen[1].get("state") != "ONLINE":
            return None
        owner = seen[1].get("owner")
        if owner == self._ctx.owner:
            return None  # our own, from before a reconnect
        return str(owner)[:100] if owner is not None else "a bridge without an owner id"

    async def watch(self) -> None:
        """End the bridge when another one took over; say ``ONLINE`` again when
        something else was published on the connection topic (a racing bridge's
        claim, or a stale last will)."""
        last = -math.inf
        while True:
            await self._wanted.wait()
            self._wanted.clear()
            if self.displaced_by is not None:
                raise RobotIdTaken(
                    f"{self._ctx.topic} was taken over by {self.displaced_by}: this "
                    "bridge stopped its robot and takes no more commands"
                )
            if self._reassert:
                await anyio.sleep(max(0.0, last + _REASSERT_INTERVAL - anyio.current_time()))
                self._reassert = False
                last = anyio.current_time()
                await self._out.publish("connection", self._online_payload, qos=1, retain=True)

    def on_connection(self, message: aiomqtt.Message) -> None:
        """A message on the connection topic, as paho hands it over (never waits).

        Raises:
            CommandError: It is not retained (no bridge's claim): refused.
        """
        raw = message.payload if isinstance(message.payload, bytes) else b""
        if raw == self._online_payload and raw:
            self.echoed.set()
            return
        if not message.retain:
            # Every bridge publishes its state retained: a message without RETAIN is
            # not a bridge's claim, and one of them must not end this bridge (it
            # would leave the robot id ONLINE with nobody behind it). Refused, and
            # reported on errors like any other (rate-limited).
            raise CommandError(
                "a connection message that is not retained is ignored (a bridge publishes "
                "its state retained)"
            )
        try:
            state = command_object(raw)
        except CommandError:
            state = {}
        if not self.echoed.is_set():
            self._before = (raw, state)  # the state our ONLINE is about to replace
            return
        owner = state.get("owner")
        taking = state.get("state") == "ONLINE" and state.get("take_over") is True
        if taking and owner != self._ctx.owner:
            # In the broker's order: every command routed to the new bridge comes
            # after this, so from here on none is acted on here.
            self.displaced_by = str(owner)[:100]
            self._lanes.clear_motion()
        elif self.online:
            self._reassert = True
        self._wanted.set()


def _clock(stamp: float) -> str:
    with contextlib.suppress(ValueError, OverflowError, OSError):
        return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(stamp))
    return repr(stamp)
