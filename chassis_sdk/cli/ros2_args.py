"""``chassis-sdk ros2``'s arguments; the command itself is
`chassis_sdk.cli.ros2_command`, imported only when it runs (it needs cyclonedds)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..core.validation import check_int
from ..devices import DeviceProfile, profile
from .arguments import (
    arg_type,
    check_record,
    deadman_args,
    device_arg,
    limit_args,
    port_args,
    record_arg,
    require_port,
)
from .extras import install_hint, require

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser"]

#: A DDS domain id, as ROS_DOMAIN_ID: 0 to 232.
DOMAIN = arg_type(int, lambda v: check_int(v, "domain_id", low=0, high=232))


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``ros2``."""
    p = sub.add_parser(
        "ros2",
        help=f"put the device on the ROS 2 graph over DDS ({install_hint('ros2')})",
        description=(
            "Bridge the device onto the ROS 2 graph with no ROS installed: cmd_vel and "
            "emergency_stop in; odom, /tf, /tf_static, battery_state, /diagnostics (and a "
            "board's imu/data_raw) out. Discovery follows ROS_DOMAIN_ID, "
            "ROS_AUTOMATIC_DISCOVERY_RANGE and ROS_STATIC_PEERS."
        ),
    )
    port_args(p)
    device_arg(p, names)
    p.add_argument("--namespace", default="", help="put every relative topic under it")
    p.add_argument(
        "--frame-prefix",
        default=None,
        metavar="PREFIX",
        help="put before every frame name (default: the namespace's, r1/ for --namespace r1)",
    )
    p.add_argument(
        "--domain-id",
        type=DOMAIN,
        default=None,
        help="DDS domain (default: $ROS_DOMAIN_ID, else 0)",
    )
    p.add_argument(
        "--stamped",
        action="store_true",
        help="read cmd_vel as geometry_msgs/TwistStamped (Jazzy's diff_drive_controller)",
    )
    p.add_argument("--no-tf", action="store_true", help="no odom -> base_link on /tf (an EKF does)")
    p.add_argument(
        "--no-description",
        action="store_true",
        help="no robot_description or joint_states (your robot_state_publisher has a URDF)",
    )
    p.add_argument("--read-only", action="store_true", help="subscribe to nothing; never write")
    p.add_argument(
        "--localhost",
        action="store_true",
        help="discover on this computer only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)",
    )
    p.add_argument(
        "--static-peer",
        action="append",
        metavar="HOST",
        help="a host always contacted by unicast (repeatable; default $ROS_STATIC_PEERS)",
    )
    limit_args(p, "cmd_vel's linear.x and angular.z")
    deadman_args(p, "a cmd_vel writer")
    record_arg(p)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    require("ros2", "ros2")
    check_record(args, "ros2")
    return _ros2(profile(args.device), port, args)


async def _ros2(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .ros2_command import ros2

    await ros2(device, port, args)
