"""``chassis-sdk bridge``: one device on an MQTT broker, for as long as the service runs.

The device is opened once, with ``reconnect=True``; the broker connection is made again
with backoff whenever it is lost (the robot is stopped first, every time). The bridge's
owner id is made once per process, so a reconnect is the same owner; ``--take-over``
applies to the first start only (a bridge that came back must never take the robot id
from one that started while it was away).
"""

from __future__ import annotations

import argparse
import socket
import ssl
import urllib.parse

import anyio

from ..core.backoff import Backoff
from ..devices import DeviceProfile
from ..errors import ChassisError
from .common import first_frame, out, read_secret_file
from .profile import device_options

__all__ = ["bridge"]

#: Reconnecting to the broker: first delay, cap (seconds).
_BACKOFF_START = 0.5
_BACKOFF_CAP = 10.0


def _broker(url: str) -> tuple[str, int, bool]:
    parsed = urllib.parse.urlsplit(url)
    if parsed.scheme not in ("mqtt", "mqtts") or not parsed.hostname:
        raise ChassisError(f"--broker must be mqtt://HOST:PORT or mqtts://HOST:PORT, got {url!r}")
    tls = parsed.scheme == "mqtts"
    try:
        port = parsed.port or (8883 if tls else 1883)
    except ValueError:
        raise ChassisError(f"--broker has a bad port: {url!r}") from None
    return parsed.hostname, port, tls


async def bridge(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Bridge until Ctrl-C or SIGTERM (then ``OFFLINE`` is published and zero written).
    The mqtt extra was checked before (`chassis_sdk.cli.extras.require`)."""
    import aiomqtt

    from ..integrations.mqtt import (
        CommandInbox,
        MqttBridge,
        RobotIdTaken,
        connection_will,
        new_owner,
    )

    host, broker_port, tls = _broker(args.broker)
    password = None
    if args.password_file:
        password = read_secret_file(args.password_file, "--password-file")
    context = None
    if tls or args.tls:
        context = ssl.create_default_context(cafile=args.cafile)
    options = device_options(args, reconnect=True, record=args.record)
    async with device.device(port, **options) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        where = f"{args.prefix}/{args.robot_id}"
        out(f"bridging {port} ({device.name}) as {where} on {args.broker}")
        backoff = Backoff(_BACKOFF_START, _BACKOFF_CAP)
        owner = new_owner()
        take_over = bool(args.take_over)
        while True:
            client = aiomqtt.Client(
                host,
                broker_port,
                # One client id per bridge process: a shared one would make the broker
                # hand the session back and forth between two bridges of one robot id.
                identifier=f"chassis-sdk-{args.prefix}-{args.robot_id}-{owner.rpartition(':')[2]}",
                protocol=aiomqtt.ProtocolVersion.V5,
                will=connection_will(args.robot_id, args.prefix, owner),
                clean_start=True,
                queue_type=CommandInbox,
                username=args.username,
                password=password,
                tls_context=context,
                timeout=5.0,
                # Replies, errors and telemetry leave at once, not after the ACK of
                # the previous packet (Nagle's algorithm and a delayed ACK: 40 ms).
                socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)],
            )
            bridge = MqttBridge(
                dev,
                client,
                args.robot_id,
                prefix=args.prefix,
                rate=args.rate,
                read_only=args.read_only,
                owner=owner,
                take_over=take_over,
                require_timestamp=args.require_timestamp,
            )
            started = anyio.current_time()
            try:
                await bridge.run()
            except RobotIdTaken:
                raise  # another bridge owns the robot id: the command ends with its one line
            except Exception as exc:
                # Anything else (the broker lost, its echo late on a slow broker, a bug
                # in one of the bridge's tasks) is retried: a service must not end on
                # it. One line each time, never a traceback.
                take_over = take_over and not bridge.online
                if anyio.current_time() - started > 5.0:
                    backoff.reset()  # it had been up: start the backoff over
                delay = backoff.next()
                what = (
                    f"broker {args.broker}: {exc}"
                    if isinstance(exc, aiomqtt.MqttError)
                    else f"bridge {where}: {type(exc).__name__}: {exc}"
                )
                stopped = "" if args.read_only else "; the robot is stopped"
                out(f"{' '.join(what.split())[:500]}{stopped}; retrying in {delay:.1f} s")
                await anyio.sleep(delay)
                continue
            take_over = take_over and not bridge.online
            await anyio.sleep(backoff.next())
