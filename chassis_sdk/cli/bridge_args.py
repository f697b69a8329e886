"""``chassis-sdk bridge``'s arguments; the command itself is
:mod:`chassis_sdk.cli.bridge_command`, imported only when it runs."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..devices import DeviceProfile, profile
from .arguments import ENV_BROKER, device_arg, port_args, positive, require_port

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``bridge``."""
    p = sub.add_parser("bridge", help="put the device on an MQTT broker (pip install '.[mqtt]')")
    port_args(p)
    device_arg(p, names)
    p.add_argument(
        "--broker",
        default=os.environ.get(ENV_BROKER) or "mqtt://127.0.0.1:1883",
        help=f"mqtt://HOST:PORT or mqtts://HOST:PORT (default: ${ENV_BROKER})",
    )
    p.add_argument("--robot-id", required=True, help="the robot's name under the prefix")
    p.add_argument("--prefix", default="robots", help="the first topic level")
    p.add_argument("--rate", type=positive("rate"), default=10.0, help="telemetry per second")
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
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    return _bridge(profile(args.device), port, args)


async def _bridge(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .bridge_command import bridge

    await bridge(device, port, args)
