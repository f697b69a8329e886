"""``chassis-sdk web``: one device in a browser dashboard, for as long as it runs.

The device is opened once, with ``reconnect=True`` and the motion limits; the page is
served until Ctrl-C, SIGTERM or ``--seconds``, and the end stops the robot if a page was
driving it (zero first), then closes every page. ``--read-only`` writes nothing no page
asked for (no zero at the end unless a page pressed STOP or E-STOP). Options are
checked before the device opens: a refused option moves nothing. The token, when one
is required, is printed once, inside the address to open.
"""

from __future__ import annotations

import argparse
import sys

import anyio

from ..devices import DeviceProfile
from ..errors import ChassisError
from .common import driven, out, read_secret_file, served_at, show_warnings, ssh_hint

__all__ = ["web"]


async def web(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Serve the dashboard until Ctrl-C, SIGTERM or ``--seconds`` (the web extra was
    checked before: `chassis_sdk.cli.extras.require`)."""
    from ..integrations.access import check_allowed_origin, check_token, is_loopback
    from ..integrations.web import GamepadMapping, WebDashboard

    token = None
    if args.token_file is not None:
        token = read_secret_file(args.token_file, "--token-file")
    origins = args.allow_origin or []
    try:  # before the device opens
        if token is not None:
            check_token(token)
        for origin in origins:
            check_allowed_origin(origin)
        gamepad = GamepadMapping(
            linear_axis=args.linear_axis,
            angular_axis=args.angular_axis,
            enable_button=args.enable_button,
            scale_linear=args.pad_scale,
            scale_angular=args.pad_scale,
        )
    except ValueError as exc:
        raise ChassisError(str(exc)) from None
    show_warnings("chassis_sdk.integrations.web", "web")  # the refusals
    # Writable even read-only: STOP and E-STOP stay offered (the dashboard, read-only,
    # sets robot.motion.zero_on_close = False: the close writes no zero nobody asked for).
    async with driven(device, port, args) as dev:
        dashboard = WebDashboard(
            dev,
            host=args.host,
            port=args.http_port,
            read_only=args.read_only,
            token=token,
            allow_origins=origins,
            command_timeout=args.command_timeout,
            gamepad=gamepad,
        )
        async with dashboard:
            mode = "read-only" if args.read_only else "drive by hand"
            # Bound to every address (0.0.0.0), the page is opened from elsewhere by
            # this computer's name; 127.0.0.1 is for a browser on this one.
            links = served_at("http", args.host, dashboard.port)
            also = f" (on this computer: {links[1]})" if len(links) > 1 else ""
            out(f"dashboard of {port} ({device.name}) at {links[0]}{also} ({mode}); Ctrl-C to quit")
            if dashboard.token is not None and token is None:
                # A token made now is printed once, as Jupyter does: the page swaps it
                # for a cookie. One from --token-file is never printed (a service's
                # output goes to its journal).
                print(f"open {links[0]}?token={dashboard.token}", file=sys.stderr)
            elif token is not None:
                print(
                    f"open {links[0]}?token=<the token in {args.token_file}>",
                    file=sys.stderr,
                )
            if not is_loopback(args.host):
                print(
                    "chassis-sdk web: the page is plain HTTP: on a network you do not "
                    f"trust, reach it over SSH instead ({ssh_hint(dashboard.port)}, then "
                    f"open http://127.0.0.1:{dashboard.port}/ there)",
                    file=sys.stderr,
                )
            with anyio.move_on_after(args.seconds):  # None: until Ctrl-C or SIGTERM
                await anyio.sleep_forever()
        stopped = "" if args.read_only else "; the robot is stopped"
        out(f"dashboard ended: {dashboard.commands} commands, {dashboard.refused} refused{stopped}")
