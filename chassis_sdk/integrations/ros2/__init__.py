"""The ROS 2 bridge on Cyclone DDS, without rclpy (the ``ros2`` extra:
``pip install -e ".[ros2]"``).

* `bridge`: `Ros2Bridge`: odometry, TF, IMU, battery, diagnostics out; ``cmd_vel`` (a
  motion-core source) and ``emergency_stop`` in;
* `dds`: participants, readers and writers, discovery;
* `graph`: the node on ``ros_discovery_info`` (``ros2 node list``);
* `description`: ``robot_description``, a URDF made from the device.
"""

from __future__ import annotations

from .bridge import (
    Ros2Bridge,
    StaticTransform,
)

__all__ = [
    "Ros2Bridge",
    "StaticTransform",
]
