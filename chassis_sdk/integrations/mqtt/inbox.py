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
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import aiomqtt

from .internals import client_internals

__all__ = [
    "READ_BATCH",
    "CommandInbox",
    "Lanes",
    "PathProbe",
    "install_batched_reads",
    "install_inbox",
]

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
        #: The epoch the velocity command in the slot was sorted in, and the time
        #: (``time.monotonic()``) it is known to have been given by at the latest.
        self._velocity_epoch = 0
        self._velocity_since = 0.0
        self._velocity_neutral = False
        #: A neutral (a zero velocity) was superseded in the slot since the last
        #: ``pop()`` of a velocity command: the sender gave it, and the motion core
        #: wants it after a block before the sender's next velocity.
        self.neutral_passed = False
        #: The velocity command last taken out by ``pop()``, its epoch and that time.
        self._taken: tuple[aiomqtt.Message, int, float] | None = None

    def __len__(self) -> int:  # what ``get()`` can return (requests are not in it)
        return len(self.urgent) + (self.velocity is not None)

    def put_velocity(
        self, message: aiomqtt.Message, since: float | None = None, *, neutral: bool = False
    ) -> bool:
        """Put ``message`` in the velocity slot (a command there before is superseded);
        ``since``: the ``time.monotonic()`` it was given by at the latest (default:
        now); ``neutral``: it is a zero. True if the slot was empty."""
        new = self.velocity is None
        if not new:
            self.superseded += 1
            self.neutral_passed |= self._velocity_neutral
        self.velocity = message
        self._velocity_neutral = neutral
        self._velocity_epoch = self.epoch
        self._velocity_since = time.monotonic() if since is None else since
        return new

    def current(self, message: aiomqtt.Message) -> bool:
        """Whether ``message``, a velocity command taken out by ``pop()``, was sorted
        after the latest stop or e-stop (only then may it act)."""
        taken = self._taken
        return taken is not None and taken[0] is message and taken[1] == self.epoch

    def since(self, message: aiomqtt.Message) -> float:
        """When ``message``, the velocity command last taken out by ``pop()``, was
        given at the latest (``time.monotonic()``; now if it is not that command)."""
        taken = self._taken
        return taken[2] if taken is not None and taken[0] is message else time.monotonic()

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
        self._taken = (message, self._velocity_epoch, self._velocity_since)
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


class PathProbe:
    """How long the broker -> bridge path has been holding what it carries, without
    the senders' clocks: the bridge publishes a small probe to itself through the
    broker every `period` (`send`), and tells this when one comes back (`back`).

    The broker sends one subscriber its messages in the order it routed them, so a
    message that arrives while a probe is still out was routed before that probe (which
    reached the broker about when it was sent): it is at least as old as that probe.
    `held` is that age for a message arriving now: the time since the oldest probe
    still out was due (or since the next probe was due, if the probing itself is late:
    the bridge's loop was held up). Sans-IO: an injected clock, no I/O.

    Args:
        period: Seconds between two probes.
        keep: Seconds of probes kept out (older ones are forgotten: one probe out
            longer than ``keep`` says as much as many).
        clock: Monotonic clock (``time.monotonic`` by default).
    """

    def __init__(
        self, period: float, keep: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.period = period
        self.keep = keep
        self._clock = clock
        #: Probes out, oldest first: (number, when it was due).
        self._out: deque[tuple[int, float]] = deque()
        self._sent = 0
        self._due: float | None = None
        #: Probes that came back.
        self.returned = 0

    def due(self) -> float | None:
        """When the next probe is due (``None`` before `start`)."""
        return self._due

    def start(self) -> None:
        """Probing begins: the first probe is due now."""
        self._due = self._clock()
        self._out.clear()

    def send(self) -> int:
        """A probe goes out now; returns its number (to put in its payload)."""
        now = self._clock()
        due = now if self._due is None else min(self._due, now)
        out = self._out
        while out and out[0][1] < now - self.keep:
            out.popleft()
        self._sent += 1
        out.append((self._sent, due))
        self._due = now + self.period
        return self._sent

    def back(self, number: int) -> bool:
        """Probe ``number`` came back: it and every probe before it are in (one lost
        by the way is settled by any after it). False if it is none of those out."""
        out = self._out
        if not out or not out[0][0] <= number <= out[-1][0]:
            return False
        while out and out[0][0] <= number:
            out.popleft()
        self.returned += 1
        return True

    def held(self) -> float:
        """How long, at least, a message arriving now has been on its way (s); 0 when
        no probe is out and the probing is on time (or has not started)."""
        now = self._clock()
        since = now
        if self._out:
            since = self._out[0][1]
        if self._due is not None:
            since = min(since, self._due)
        return max(0.0, now - since)


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
    """The client's `CommandInbox`: its own (``queue_type=CommandInbox``), or one put in
    place of aiomqtt's default queue (which must be empty: the client is not entered
    yet).

    Raises:
        TypeError: The client's incoming queue cannot be replaced.
    """
    try:
        queue = client_internals(client).queue
    except TypeError as exc:
        raise TypeError(f"the client's incoming queue cannot be replaced: {exc}") from None
    if isinstance(queue, CommandInbox):
        return queue
    if not queue.empty():
        raise TypeError(
            "the client's incoming queue cannot be replaced: make it with queue_type=CommandInbox"
        )
    # aiomqtt's default queue is unbounded and first in, first out: under a flood it
    # grows without bound and a stop waits behind everything. The client is not
    # entered yet, so nothing can be in it.
    inbox = CommandInbox()
    client_internals(client, new_queue=inbox)
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
    # aiomqtt's reader calls its paho client's ``loop_read()`` once per readable event:
    # that method, of this client only, reads on (aiomqtt has no hook for it; pinned by
    # ``test_each_wake_up_of_the_client_s_socket_reads_a_batch_of_packets``).
    paho = client_internals(client).paho
    if "loop_read" in vars(paho):
        return  # installed already
    read_one = paho.loop_read

    def loop_read(max_packets: int = 1) -> Any:
        rc = read_one()
        for _ in range(batch - 1):
            sock = paho.socket()
            if rc != 0 or sock is None or not _pending(sock):
                break
            rc = read_one()
        return rc

    paho.loop_read = loop_read  # type: ignore[method-assign]  # this client only
