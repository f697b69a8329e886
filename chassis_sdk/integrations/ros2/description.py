"""The robot's description for RViz without a description package: a URDF made from the
device (`urdf`), which the bridge publishes on ``robot_description`` (latched), beside
the wheels' ``joint_states``; robot_state_publisher turns both into the wheels' frames,
and RViz's RobotModel draws the base.

The URDF holds ``base_link`` (a box the size of the base: the wheelbase plus a wheel's
diameter long, the track less a wheel's width wide), a continuous joint and a cylinder
for each wheel (axis ``y``: a positive angle rolls the base forward), and a fixed joint
for each static transform whose parent is in it (a board's ``imu_link``). Link names
carry the options' frame prefix (``r1/base_link``), as the odometry does; joint names
do not (``joint_states`` are per robot, under its namespace).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable

from ...core.geometry import Geometry
from ...recording.ros2_types import Ros2Options

__all__ = ["urdf"]

#: A base that reports no size (a board) is drawn as a box this size (m), so that RViz
#: shows where it is; its frames are right, its size is not known.
UNKNOWN_SIZE = (0.2, 0.2, 0.05)


def _num(value: float) -> str:
    return f"{value:.6g}"


def _xyz(*values: float) -> str:
    return " ".join(_num(v) for v in values)


def _link(robot: ET.Element, name: str, shape: ET.Element | None = None, **origin: str) -> None:
    link = ET.SubElement(robot, "link", name=name)
    if shape is None:
        return
    for part in ("visual", "collision"):
        element = ET.SubElement(link, part)
        if origin:
            ET.SubElement(element, "origin", attrib=dict(origin))
        geometry = ET.SubElement(element, "geometry")
        geometry.append(shape)
        if part == "visual":
            material = ET.SubElement(element, "material", name=f"{name}_color")
            dark = "wheel" in name
            ET.SubElement(material, "color", rgba="0.15 0.15 0.15 1" if dark else "0.85 0.45 0.1 1")


def _joint(
    robot: ET.Element,
    name: str,
    kind: str,
    parent: str,
    child: str,
    xyz: str,
    rpy: str = "0 0 0",
) -> ET.Element:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=xyz, rpy=rpy)
    return joint


def urdf(
    geometry: Geometry | None,
    options: Ros2Options,
    streams: Iterable[str] = (),
    *,
    name: str = "chassis",
) -> str:
    """The URDF of a base: its size from ``geometry`` (``None``: `UNKNOWN_SIZE` and no
    wheels), its frames from ``options``, its static transforms from the device's
    ``streams`` (a board's IMU link).

    Raises:
        ValueError: ``name`` is empty.
    """
    if not name:
        raise ValueError("a robot's name must not be empty")
    robot = ET.Element("robot", name=name)
    base = options.frame(options.child_frame_id)
    if geometry is None:
        _link(robot, base, ET.Element("box", size=_xyz(*UNKNOWN_SIZE)))
    else:
        r = geometry.wheel_radius
        width = max(0.01, 0.4 * r)  # a wheel's width, drawn
        length = geometry.wheelbase + 2 * r
        inner = max(0.05, geometry.track_width - width)
        _link(robot, base, ET.Element("box", size=_xyz(length, inner, r)))
        for wheel in geometry.wheels:
            x, y = geometry.place(wheel)
            link = options.frame(f"{wheel}_wheel")
            cylinder = ET.Element("cylinder", radius=_num(r), length=_num(width))
            _link(robot, link, cylinder, rpy="1.5707963 0 0")  # its axis along y
            joint = _joint(robot, f"{wheel}_wheel_joint", "continuous", base, link, _xyz(x, y, 0))
            ET.SubElement(joint, "axis", xyz="0 1 0")
    links = {base}
    for st in options.static_for(streams):
        if st.parent in links and st.child not in links:
            _link(robot, st.child)
            _joint(
                robot,
                f"{st.child.rsplit('/', 1)[-1]}_joint",
                "fixed",
                st.parent,
                st.child,
                _xyz(st.x, st.y, st.z),
                _xyz(0, 0, st.yaw),
            )
            links.add(st.child)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
