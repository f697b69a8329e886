"""What each part of a bridge is given: a narrow, frozen context, not the bridge.

`MqttBridge` (``bridge``) builds one for each of its parts from its options, once: the
publishing side (`PublishContext`), the robot id's ownership (`OwnershipContext`) and
the command side (`CommandContext`). Each holds only what that part reads, so no part
imports the bridge, and what a part depends on is written here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import aiomqtt

from ...core.device import Device
from ...devices import DeviceProfile

__all__ = ["CommandContext", "OwnershipContext", "PublishContext"]


@dataclass(frozen=True, slots=True)
class PublishContext:
    """What the publishing side (`Publisher`) reads."""

    #: The bridge's client (entered by the bridge).
    client: aiomqtt.Client
    #: ``{prefix}/{robot_id}``: every topic the bridge publishes is under it.
    topic: str
    device: Device[Any, Any]
    profile: DeviceProfile
    #: The bridge's owner id (in ``connection``, ``info`` and the probe).
    owner: str
    #: Most telemetry messages per stream per second.
    rate: float


@dataclass(frozen=True, slots=True)
class OwnershipContext:
    """What the robot id's ownership (`Ownership`) reads."""

    client: aiomqtt.Client
    topic: str
    owner: str
    #: Start even if another bridge is ``ONLINE`` for the robot id.
    take_over: bool


@dataclass(frozen=True, slots=True)
class CommandContext:
    """What the command side (`Commands`) reads."""

    client: aiomqtt.Client
    topic: str
    #: The first topic level (a response topic must stay out of its robots' subtrees).
    prefix: str
    device: Device[Any, Any]
    profile: DeviceProfile
    owner: str
    #: Never act on a command (requests are still answered).
    read_only: bool
    #: Refuse velocity commands and e-stop releases without a ``timestamp``.
    require_timestamp: bool
    #: The oldest a command may be, by its ``timestamp`` (s).
    max_age: float
    #: The device's deadman (s): a stamped command holds until its stamp plus this.
    deadman: float
