"""``chassis-sdk serve``: one device, live in the Foxglove app, for as long as it runs.

The device is opened once, with ``reconnect=True``; Ctrl-C or SIGTERM stops the robot
at once if a Teleop client was driving, then the server (without blocking the event
loop: a client that does not read cannot hold the stop), then the device (zero
velocity first, as always).

Who may connect is checked before the device opens: ``--host`` beyond loopback needs
a token: ``--token``/``--token-file``, else one is made and printed once, inside the
address to open, as ``web`` does (``--no-token`` serves without one); ``--allow-origin``
values must be origins. A token given is never printed.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import anyio

from ..devices import DeviceProfile
from ..errors import ChassisError
from .common import driven, out, read_secret_file, served_at, show_warnings

__all__ = ["serve", "serve_token"]


def serve_token(host: str, token: str | None, no_token: bool) -> tuple[str | None, bool]:
    """The token ``serve`` requires, and whether it was made now: the one given; else,
    beyond loopback and without ``--no-token``, a new one (printed once, as ``web``
    prints its own: a command-line user is never told of ``allow_no_token=True``);
    else none."""
    from ..integrations.access import made_token

    return made_token(host, token, none=no_token)


async def serve(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Serve until Ctrl-C, SIGTERM or ``--seconds`` (the foxglove extra was checked
    before: `chassis_sdk.cli.extras.require`)."""
    from ..integrations.foxglove import FoxgloveServer, check_access

    if args.token is not None and args.token_file is not None:
        raise ChassisError("give --token or --token-file, not both")
    token = args.token
    if args.token_file is not None:
        token = read_secret_file(args.token_file, "--token-file")
    if token is None and os.environ.get("CHASSIS_SDK_FOXGLOVE_TOKEN"):
        token = os.environ["CHASSIS_SDK_FOXGLOVE_TOKEN"]
    token, made = serve_token(args.host, token, args.no_token)
    origins = args.allow_origin or []
    try:  # before the device opens: a refused option moves nothing
        check_access(args.host, allow_origins=origins, token=token, allow_no_token=args.no_token)
    except ValueError as exc:
        raise ChassisError(str(exc)) from None
    show_warnings("chassis_sdk.integrations.foxglove", "serve")  # the refusals
    # FILE.mcap: the server's recorder, one sink for the file and the clients; any
    # other name: the device's own record= (JSON lines), as every command records.
    mcap = args.record if args.record and Path(args.record).suffix.lower() == ".mcap" else None
    async with driven(device, port, args, record=mcap is None) as dev:
        try:
            server = FoxgloveServer(
                dev,
                host=args.host,
                port=args.foxglove_port,
                read_only=args.read_only,
                record=mcap,
                allow_origins=origins,
                token=token,
                allow_no_token=args.no_token,
            )
            server.start()
        except RuntimeError as exc:  # the address is taken, or cannot be bound
            raise ChassisError(f"cannot serve on {args.host}:{args.foxglove_port}: {exc}") from None
        try:
            mode = "read-only" if args.read_only else "Teleop and services on"
            access = "token required" if token is not None else "no token"
            links = [link.rstrip("/") for link in served_at("ws", args.host, server.port)]
            also = f" (on this computer: {links[1]})" if len(links) > 1 else ""
            out(
                f"serving {port} ({device.name}) to Foxglove at {links[0]}{also} ({mode}; {access})"
            )
            if token is None and args.no_token:
                print(
                    f"chassis-sdk serve: WARNING: {args.host} without a token: anyone who "
                    "reaches the port can drive the robot",
                    file=sys.stderr,
                )
            if made:  # printed once, as web prints its own
                address = f"{links[0]}?token={token}"
                print(
                    f"open {address} in the Foxglove app (Open connection > Foxglove "
                    "WebSocket); Ctrl-C to quit",
                    file=sys.stderr,
                )
            else:
                print(
                    "open it in the Foxglove app (Open connection > Foxglove WebSocket"
                    + ("; add ?token=<the token> to the address" if token is not None else "")
                    + "); Ctrl-C to quit",
                    file=sys.stderr,
                )
            with anyio.move_on_after(args.seconds):  # None: until Ctrl-C or SIGTERM
                await anyio.sleep_forever()
        finally:
            # Never blocks the loop (the device's deadman goes on meanwhile); a robot
            # a Teleop client was driving gets its zero first.
            await server.aclose()
