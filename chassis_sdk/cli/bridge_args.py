"""``chassis-sdk bridge``'s arguments; the command itself is
`chassis_sdk.cli.bridge_command`, imported only when it runs."""

from __future__ import annotations

import argparse
import os
import urllib.parse
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from ..core.validation import check_real
from ..devices import DeviceProfile, profile
from ..integrations.inbound import check_topic_level
from .arguments import (
    ENV_BROKER,
    arg_type,
    check_record,
    device_arg,
    port_args,
    record_arg,
    require_port,
)
from .extras import install_hint, require

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["BROKER", "RATE", "add_parser", "broker_url", "topic_level"]


def broker_url(url: str) -> str:
    """``url`` if it is ``mqtt://HOST[:PORT]`` or ``mqtts://HOST[:PORT]`` with a port
    from 1 to 65535.

    Raises:
        ValueError: Anything else (``http://x``, no host, a bad port), in one line.
    """
    parsed = urllib.parse.urlsplit(url)
    if parsed.scheme not in ("mqtt", "mqtts") or not parsed.hostname:
        raise ValueError(f"must be mqtt://HOST:PORT or mqtts://HOST:PORT, got {url!r}")
    try:
        port = parsed.port
    except ValueError:
        port = -1
    if port is not None and not 1 <= port <= 65535:
        raise ValueError(f"has a bad port (1 to 65535): {url!r}")
    return url


def topic_level(name: str) -> Callable[[str], str]:
    """One MQTT topic level, named ``name`` in the refusal (the rule
    `MqttBridge` applies, checked while parsing so
    nothing is opened or printed first)."""
    return arg_type(str, lambda value: check_topic_level(value, name))


#: ``--broker``: checked while parsing, like its default from ``$CHASSIS_SDK_BROKER``.
BROKER = arg_type(str, broker_url)
#: ``--rate``: telemetry messages a second, as the bridge takes them (above 0, at most 100).
RATE = arg_type(
    float, lambda v: check_real(v, "rate", low=0, low_open=True, high=100, unit="per second")
)


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``bridge``."""
    p = sub.add_parser("bridge", help=f"put the device on an MQTT broker ({install_hint('mqtt')})")
    port_args(p)
    device_arg(p, names)
    p.add_argument(
        "--broker",
        type=BROKER,
        default=os.environ.get(ENV_BROKER) or "mqtt://127.0.0.1:1883",
        help=f"mqtt://HOST:PORT or mqtts://HOST:PORT (default: ${ENV_BROKER})",
    )
    p.add_argument(
        "--robot-id",
        required=True,
        type=arg_type(str, topic_level("robot_id")),
        help="the robot's name under the prefix (letters, digits, '-', '_')",
    )
    p.add_argument(
        "--prefix",
        type=arg_type(str, topic_level("prefix")),
        default="robots",
        help="the first topic level (letters, digits, '-', '_')",
    )
    p.add_argument("--rate", type=RATE, default=10.0, help="telemetry per second (at most 100)")
    p.add_argument("--read-only", action="store_true", help="never take a command")
    p.add_argument(
        "--take-over", action="store_true", help="start even if another bridge has this robot id"
    )
    p.add_argument(
        "--require-timestamp",
        action="store_true",
        help="refuse velocity commands without a 'timestamp' (clocks must be in sync)",
    )
    p.add_argument("--username", help="broker user name")
    p.add_argument("--password-file", help="a file holding the broker password")
    p.add_argument("--tls", action="store_true", help="TLS (implied by mqtts://)")
    p.add_argument("--cafile", help="CA certificates for TLS (default: the system's)")
    record_arg(p)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    require("bridge", "mqtt")
    check_record(args, "bridge")
    return _bridge(profile(args.device), port, args)


async def _bridge(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .bridge_command import bridge

    await bridge(device, port, args)
