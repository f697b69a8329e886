"""The ROS 2 bridge on Cyclone DDS, without rclpy (``pip install 'chassis-sdk[ros2]'``).

* `bridge`: `Ros2Bridge`: odometry, TF, IMU, battery, diagnostics out; ``cmd_vel`` (a
  motion-core source) and ``emergency_stop`` in;
* `dds`: participants, readers and writers, discovery, ``ros_discovery_info``.
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
