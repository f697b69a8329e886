"""A bridge's incoming queue: each message sorted into its lane as paho hands it over.

`CommandInbox` is the ``queue_type`` of a bridge's ``aiomqtt.Client``; its
`Lanes` hold what is pending, by kind (stops and e-stops first, one slot for the
newest velocity command, a short queue of requests), so memory stays bounded and a stop
is served before anything else, whatever the rate of messages. The sorting itself is the
bridge's (`MqttBridge`); see the module docstring
of `chassis_sdk.integrations.mqtt` for what goes where.
"""

from __future__ import annotations

import array
import asyncio
import fcntl
import logging
import termios
from collections import deque
from collections.abc import Callable
from typing import Any

import aiomqtt

__all__ = ["READ_BATCH", "CommandInbox", "Lanes", "install_batched_reads", "install_inbox"]

_log = logging.getLogger("chassis_sdk.integrations.mqtt")

#: Stops and e-stops pending before a run of them is collapsed to what it means.
_URGENT_MAX = 16

#: Packets read at most per wake-up of the client's socket (see `install_batched_reads`).
READ_BATCH = 64


class Lanes:
    """What is pending, by kind: stops and e-stops (first), the newest velocity
    command, and requests (served by workers of their own)."""

    def __init__(self) -> None:
        #: ("engage" | "stop" | "release", message), in arrival order.
        self.urgent: deque[tuple[str, aiomqtt.Message]] = deque()
        self.velocity: aiomqtt.Message | None = None
        self.requests: deque[aiomqtt.Message] = deque()
        #: Commands dropped because a newer one made them moot.
        self.superseded = 0
        #: Stops and e-stops sorted so far (and take-overs): a velocity command sorted
        #: before the latest of them must never act, wherever it is when it moves on.
        self.epoch = 0
        #: The epoch the velocity command in the slot was sorted in.
        self._velocity_epoch = 0
        #: The velocity command last taken out by ``pop()``, and its epoch.
        self._taken: tuple[aiomqtt.Message, int] | None = None

    def __len__(self) -> int:  # what ``get()`` can return (requests are not in it)
        return len(self.urgent) + (self.velocity is not None)

    def put_velocity(self, message: aiomqtt.Message) -> bool:
        new = self.velocity is None
        if not new:
            self.superseded += 1
        self.velocity = message
        self._velocity_epoch = self.epoch
        return new

    def current(self, message: aiomqtt.Message) -> bool:
        """Whether ``message``, a velocity command taken out by ``pop()``, was sorted
        after the latest stop or e-stop (only then may it act)."""
        taken = self._taken
        return taken is not None and taken[0] is message and taken[1] == self.epoch

    def put_back(self, message: aiomqtt.Message) -> None:
        """Return a velocity command taken out by ``pop()`` to its slot, to wait there
        for its period: dropped if a stop or e-stop came after it (paho sorted one
        while it was out of the slot, so the stop could not cancel it), or if a newer
        velocity command is in the slot already."""
        if self.velocity is not None or not self.current(message):
            self.superseded += 1
            return
        self.velocity = message
        self._velocity_epoch = self.epoch

    def put_urgent(self, kind: str, message: aiomqtt.Message) -> bool:
        self.epoch += 1  # a velocity command out of its slot now cannot act either
        if self.velocity is not None:  # it came before this stop: it must not follow it
            self.velocity = None
            self.superseded += 1
        urgent = self.urgent
        if urgent and urgent[-1][0] == kind:  # the same again means the same
            if kind != "engage":
                urgent[-1] = (kind, message)
            self.superseded += 1
            return False
        urgent.append((kind, message))
        if len(urgent) > _URGENT_MAX:
            self._collapse()
        return True

    def _collapse(self) -> None:
        """A long run of stops and e-stops, as what it means: e-stopped if any engaged,
        stopped, and released last only if the last e-stop command was a release."""
        urgent = self.urgent
        engage = next((x for x in urgent if x[0] == "engage"), None)
        stop = next((x for x in reversed(urgent) if x[0] == "stop"), None)
        last = next((x for x in reversed(urgent) if x[0] != "stop"), None)
        kept = [x for x in (engage, stop) if x is not None]
        if last is not None and last[0] == "release":
            kept.append(last)
        self.superseded += len(urgent) - len(kept)
        urgent.clear()
        urgent.extend(kept)

    def pop(self) -> aiomqtt.Message:
        if self.urgent:
            return self.urgent.popleft()[1]
        message, self.velocity = self.velocity, None
        assert message is not None  # asyncio.Queue gets only when len() > 0
        self._taken = (message, self._velocity_epoch)
        return message

    def clear(self) -> None:
        """Drop every pending command."""
        self.epoch += 1
        self.superseded += len(self)
        self.urgent.clear()
        self.velocity = None
        self.requests.clear()

    def clear_motion(self) -> None:
        """Drop whatever could move the robot (the velocity command, releases)."""
        self.epoch += 1
        if self.velocity is not None:
            self.velocity = None
            self.superseded += 1
        kept = [x for x in self.urgent if x[0] != "release"]
        self.superseded += len(self.urgent) - len(kept)
        self.urgent.clear()
        self.urgent.extend(kept)


class CommandInbox(asyncio.Queue[aiomqtt.Message]):
    """The incoming queue of a bridge's client (aiomqtt's ``queue_type``): each message
    is sorted as it arrives, by `MqttBridge`, so
    memory stays bounded and a stop is served before anything else, whatever the rate
    of messages.

    Pass ``queue_type=CommandInbox`` to ``aiomqtt.Client``; a bridge given a client
    with aiomqtt's default queue (unbounded, first in first out) puts one in.
    """

    def _init(self, maxsize: int) -> None:
        self.lanes = Lanes()
        # asyncio.Queue's empty() and qsize() read the length of self._queue.
        self._queue = self.lanes
        #: Sorts one message (set by the bridge); True when it is pending in a lane
        #: that ``get()`` serves and was not there before.
        self.sort: Callable[[aiomqtt.Message], bool] = self._unbound

    def _unbound(self, message: aiomqtt.Message) -> bool:
        _log.debug("no bridge on this inbox: dropped %s", message.topic)
        return False

    def put_nowait(self, item: aiomqtt.Message) -> None:
        # Called by aiomqtt for every message, inside paho's read callback: nothing
        # here may raise (the connection would be dropped) and nothing may wait.
        if self.sort(item):
            super().put_nowait(item)  # counts it and wakes the reader

    def _put(self, item: aiomqtt.Message) -> None:
        pass  # already stored in its lane by sort()

    def _get(self) -> aiomqtt.Message:
        return self.lanes.pop()


def install_inbox(client: aiomqtt.Client) -> CommandInbox:
    """The client's `CommandInbox`: its own, or one put in place of aiomqtt's
    default queue (which must be empty: the client is not entered yet).

    Raises:
        TypeError: The client's incoming queue cannot be replaced.
    """
    queue = getattr(client, "_queue", None)
    if isinstance(queue, CommandInbox):
        inbox = queue
    elif isinstance(queue, asyncio.Queue) and queue.empty():
        # aiomqtt's default queue is unbounded and first in, first out: under a
        # flood it grows without bound and a stop waits behind everything. The
        # client is not entered yet, so nothing can be in it.
        inbox = CommandInbox()
        client._queue = inbox
    else:
        raise TypeError(
            "the client's incoming queue cannot be replaced: make it with queue_type=CommandInbox"
        )
    return inbox


def _pending(sock: Any) -> int:
    """Bytes the kernel holds for ``sock`` (TCP, Unix), or TLS's decoded bytes; 0 when
    that cannot be told (a socket of another kind: the next wake-up reads on)."""
    pending = getattr(sock, "pending", None)
    if pending is not None and pending() > 0:
        return 1
    count = array.array("i", [0])
    try:
        fcntl.ioctl(sock.fileno(), termios.FIONREAD, count)
    except (OSError, ValueError, AttributeError):
        return 0
    return count[0]


def install_batched_reads(client: aiomqtt.Client, batch: int = READ_BATCH) -> None:
    """Let the client read up to ``batch`` packets each time its socket wakes the loop.

    paho's ``loop_read()`` reads one packet of QoS 0 per call, and aiomqtt calls it
    once per readable event: each message then costs a turn of the event loop (an
    ``epoll`` and the loop's bookkeeping), the larger part of its cost. Under a flood
    the bridge fell behind the broker, its socket filled, and a stop or e-stop waited
    behind every message before it (hundreds of milliseconds; the broker's keepalive
    could run out). Here each wake-up reads on while the kernel holds more bytes, up to
    ``batch`` packets, then lets the loop run (the e-stop sorted meanwhile is acted on
    at once). Nothing else changes: the same paho calls, in the same order.
    """
    if batch < 1:
        raise ValueError(f"batch must be at least 1, got {batch!r}")
    paho = client._client
    if "loop_read" in vars(paho):
        return  # installed already
    read_one = paho.loop_read

    def loop_read(max_packets: int = 1) -> Any:
        rc = read_one()
        for _ in range(batch - 1):
            sock = paho._sock
            if rc != 0 or sock is None or not _pending(sock):
                break
            rc = read_one()
        return rc

    paho.loop_read = loop_read  # type: ignore[method-assign]  # this client only
