"""``chassis-sdk bridge``: one device on an MQTT broker, for as long as the service runs.

The device is opened once, with ``reconnect=True``; the broker connection is made again
with backoff whenever it is lost (the robot is stopped first, every time).
"""

from __future__ import annotations

import argparse
import asyncio
import ssl
import urllib.parse
from pathlib import Path

from ..core.backoff import Backoff
from ..devices import DeviceProfile
from ..errors import ChassisError
from .common import first_frame, out

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
    """Bridge until Ctrl-C or SIGTERM (then ``OFFLINE`` is published and zero written)."""
    try:
        import aiomqtt

        from ..bridge import MqttBridge, connection_will
    except ImportError:
        raise ChassisError("bridge needs aiomqtt: pip install 'chassis-sdk[mqtt]'") from None
    host, broker_port, tls = _broker(args.broker)
    password = None
    if args.password_file:
        try:
            password = Path(args.password_file).read_text().strip()  # noqa: ASYNC240 (once, small)
        except OSError as exc:
            raise ChassisError(f"cannot read --password-file: {exc.strerror}") from None
    context = None
    if tls or args.tls:
        context = ssl.create_default_context(cafile=args.cafile)
    async with device.device(port, baudrate=args.baudrate, reconnect=True) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        where = f"{args.prefix}/{args.robot_id}"
        out(f"bridging {port} ({device.name}) as {where} on {args.broker}")
        backoff = Backoff(_BACKOFF_START, _BACKOFF_CAP)
        while True:
            client = aiomqtt.Client(
                host,
                broker_port,
                identifier=f"chassis-sdk-{args.prefix}-{args.robot_id}",
                protocol=aiomqtt.ProtocolVersion.V5,
                will=connection_will(args.robot_id, args.prefix),
                clean_start=True,
                username=args.username,
                password=password,
                tls_context=context,
                timeout=5.0,
            )
            bridge = MqttBridge(
                dev,
                client,
                args.robot_id,
                prefix=args.prefix,
                rate=args.rate,
                read_only=args.read_only,
            )
            started = asyncio.get_running_loop().time()
            try:
                await bridge.run()
            except aiomqtt.MqttError as exc:
                if asyncio.get_running_loop().time() - started > 5.0:
                    backoff.reset()  # it had been up: start the backoff over
                delay = backoff.next()
                out(f"broker {args.broker}: {exc}; the robot is stopped; retrying in {delay:.1f} s")
                await asyncio.sleep(delay)
                continue
            await asyncio.sleep(backoff.next())
