"""``chassis-sdk ros2``: one device on the ROS 2 graph, for as long as the service runs.

The device is opened once, with ``reconnect=True`` and the motion limits; the bridge
runs until Ctrl-C, SIGTERM or ``--seconds``, and its end stops the robot (zero first,
then the DDS endpoints go, so peers learn at once). Options are checked before the
device opens: a refused option moves nothing.
"""

from __future__ import annotations

import argparse
import sys

import anyio

from ..devices import DeviceProfile
from ..errors import ChassisError
from .common import driven, out, show_warnings

__all__ = ["ros2"]


async def ros2(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Bridge until Ctrl-C, SIGTERM or ``--seconds`` (the ros2 extra was checked before:
    `chassis_sdk.cli.extras.require`)."""
    from ..integrations.ros2 import Ros2Bridge
    from ..integrations.ros2.dds import discovery_from_env
    from ..recording.ros2_types import Ros2Options

    try:  # before the device opens
        names = Ros2Options(namespace=args.namespace, frame_prefix=args.frame_prefix)
        namespace = names.namespace
        discovery = discovery_from_env(
            domain_id=args.domain_id,
            localhost=args.localhost or None,
            static_peers=args.static_peer,
        )
    except (TypeError, ValueError) as exc:
        raise ChassisError(str(exc)) from None
    show_warnings("chassis_sdk.integrations.ros2", "ros2")  # the refusals
    # A viewer writes nothing, not even the zero at close.
    async with driven(device, port, args, read_only=args.read_only) as dev:
        bridge = Ros2Bridge(
            dev,
            namespace=namespace,
            discovery=discovery,
            stamped=args.stamped,
            tf=not args.no_tf,
            read_only=args.read_only,
            command_timeout=args.command_timeout,
            frame_prefix=args.frame_prefix,
            description=not args.no_description,
        )
        async with anyio.create_task_group() as tg:
            tg.start_soon(bridge.run, name="ros2 bridge")
            await bridge.started.wait()
            where = namespace or "/"
            mode = "read-only" if args.read_only else "cmd_vel and emergency_stop in"
            out(
                f"bridging {port} ({device.name}) onto ROS 2 domain {discovery.domain_id} "
                f"under {where} ({discovery.range.lower()} discovery; {mode}); Ctrl-C to quit"
            )
            if not args.read_only and discovery.range != "LOCALHOST":
                print(
                    "chassis-sdk ros2: WARNING: DDS has no authentication here: any computer "
                    f"that reaches this one in domain {discovery.domain_id} can drive the "
                    "robot (--localhost keeps the graph on this computer)",
                    file=sys.stderr,
                )
            with anyio.move_on_after(args.seconds):  # None: until Ctrl-C or SIGTERM
                await anyio.sleep_forever()
            tg.cancel_scope.cancel()
        stopped = "" if args.read_only else "; the robot is stopped"
        out(f"bridge ended: {bridge.commands} commands, {bridge.refused} refused{stopped}")
