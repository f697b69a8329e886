"""The one place the bridge reaches into ``aiomqtt.Client``: `client_internals`.

Everything else of the package uses aiomqtt's and paho's public API (paho's ``Client``
through its public methods: ``publish``, ``socket``, ``want_write``, ``loop_read``,
``disconnect``). aiomqtt 2 has no public way to these three, and its maintainers
decline to expose the paho client (https://github.com/empicano/aiomqtt/issues/191):

* ``_client``, the paho client: telemetry handed to the connection without a wait per
  message (`send_latest`, `unwritten`), a batch of packets read per wake-up
  (`install_batched_reads`), and the DISCONNECT with reason 0x04 that makes the broker
  publish the last will (aiomqtt's ``__aexit__`` always sends reason 0, which cancels
  it);
* ``_queue``, the client's incoming queue made from its ``queue_type``: the bridge
  binds its `CommandInbox` to itself, and puts one in place of aiomqtt's default queue
  when the client was made without ``queue_type=CommandInbox``;
* ``_disconnected``, the future aiomqtt completes when the connection ends: waited for
  after that DISCONNECT (so aiomqtt's exit sends no second one), and the cause of the
  error raised when the client is not connected (as ``publish`` raises it).

A release of aiomqtt that changes them makes `client_internals` raise `TypeError`,
which `tests/test_bridge_hostile.py` (``test_the_aiomqtt_internals_the_bridge_uses``)
pins: an upgrade fails a test, not the robot. aiomqtt is pinned below 3 for them
(``pyproject.toml``).
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

import aiomqtt
from paho.mqtt import client as paho

__all__ = ["ClientInternals", "client_internals"]


@dataclass(frozen=True, slots=True)
class ClientInternals:
    """An ``aiomqtt.Client``'s parts the bridge uses, as they are now (``disconnected``
    is a new future each time the client is entered: read them when used)."""

    #: The paho client that holds the connection (used by its public methods only).
    paho: paho.Client
    #: The incoming queue ``client.messages`` reads (``queue_type``'s instance).
    queue: asyncio.Queue[aiomqtt.Message]
    #: Done when the connection ended (an exception: it was lost).
    disconnected: asyncio.Future[None]


def client_internals(
    client: aiomqtt.Client, *, new_queue: asyncio.Queue[aiomqtt.Message] | None = None
) -> ClientInternals:
    """``client``'s paho client, incoming queue and disconnection future; with
    ``new_queue``, that queue first put in place of the client's (which must not be
    entered yet: nothing is in its queue).

    Raises:
        TypeError: This version of aiomqtt does not have them as aiomqtt 2 does.
    """
    inner = getattr(client, "_client", None)
    disconnected = getattr(client, "_disconnected", None)
    if new_queue is not None and hasattr(client, "_queue"):
        client._queue = new_queue
    queue = getattr(client, "_queue", None)
    if not (
        isinstance(inner, paho.Client)
        and isinstance(queue, asyncio.Queue)
        and isinstance(disconnected, asyncio.Future)
    ):
        raise TypeError(
            f"aiomqtt {getattr(aiomqtt, '__version__', '?')} is not as the MQTT bridge "
            "knows it (its Client's _client, _queue and _disconnected; aiomqtt<3 is required)"
        )
    return ClientInternals(inner, queue, disconnected)
