"""The MQTT bridge: a device on a fleet's broker (``pip install -e ".[mqtt]"``).

* `bridge`: `MqttBridge`, the bridge;
* `commands`: the commands it takes, sorted and acted on through its motion-core source;
* `inbox`: paho's messages into bounded lanes, and the probe of the broker -> bridge path;
* `ownership`: one bridge per robot id, and taking over;
* `publish`: what it publishes (telemetry, state, errors, the probe).
"""

from __future__ import annotations

from .bridge import (
    CommandError,
    CommandInbox,
    MqttBridge,
    RobotIdTaken,
    connection_will,
    new_owner,
)

__all__ = [
    "CommandError",
    "CommandInbox",
    "MqttBridge",
    "RobotIdTaken",
    "connection_will",
    "new_owner",
]
