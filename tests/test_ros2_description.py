"""The robot's description for RViz: the URDF made from a device (checked by urdfdom's
``check_urdf``, ROS's own parser), the wheels' joint states from telemetry (a table on
injected timestamps), and the size's rules. Over DDS against a Fast DDS peer:
``test_ros2_interop.py::test_rviz_draws_the_robot_from_its_robot_description_and_joint_states``.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any
from xml.etree import ElementTree

import pytest

from chassis_sdk import Geometry
from chassis_sdk.core.geometry import FOUR_WHEELS
from chassis_sdk.integrations.ros2.description import UNKNOWN_SIZE, urdf
from chassis_sdk.recording.ros2_types import JOINT_GAP, Ros2Options, StaticTransform, Translator

from .support.urdf import check_urdf

SIZE = Geometry(track_width=0.725, wheelbase=0.5, wheel_radius=0.085)


def _joints(text: str) -> dict[str, ElementTree.Element]:
    return {str(j.get("name")): j for j in ElementTree.fromstring(text).iter("joint")}


@pytest.mark.integration  # check_urdf runs as a process
def test_a_chassis_is_its_size_and_four_wheels_that_roll_it_forward() -> None:
    text = urdf(SIZE, Ros2Options(), ["telemetry", "odometry"])
    tree = check_urdf(text)
    assert "root Link: base_link has 4 child(ren)" in tree
    joints = _joints(text)
    assert sorted(joints) == sorted(f"{w}_wheel_joint" for w in FOUR_WHEELS)
    for wheel, (x, y) in {
        "front_left": (0.25, 0.3625),
        "front_right": (0.25, -0.3625),
        "rear_left": (-0.25, 0.3625),
        "rear_right": (-0.25, -0.3625),
    }.items():
        joint = joints[f"{wheel}_wheel_joint"]
        assert joint.get("type") == "continuous"
        origin, axis = joint.find("origin"), joint.find("axis")
        assert origin is not None
        assert axis is not None
        assert [float(v) for v in str(origin.get("xyz")).split()] == [x, y, 0.0]
        assert axis.get("xyz") == "0 1 0"  # a positive angle rolls forward
    cylinders = ElementTree.fromstring(text).iter("cylinder")
    assert {float(str(c.get("radius"))) for c in cylinders} == {0.085}


@pytest.mark.integration  # check_urdf runs as a process
def test_a_board_without_a_size_is_a_small_box_with_its_imu_link() -> None:
    text = urdf(None, Ros2Options(namespace="r2"), ["imu", "velocity", "battery"])
    tree = check_urdf(text)
    assert "root Link: r2/base_link has 1 child(ren)" in tree
    assert "r2/imu_link" in tree
    (imu,) = _joints(text).values()
    assert imu.get("type") == "fixed"
    boxes = {str(box.get("size")) for box in ElementTree.fromstring(text).iter("box")}
    assert [[float(v) for v in size.split()] for size in boxes] == [list(UNKNOWN_SIZE)]


@pytest.mark.integration  # check_urdf runs as a process
def test_static_transforms_join_the_tree_only_under_a_link_of_it() -> None:
    laser = StaticTransform("base_link", "laser", x=0.2, z=0.1, yaw=math.pi)
    stray = StaticTransform("map", "beacon")  # not under base_link: URDF has one root
    text = urdf(SIZE, Ros2Options(static_transforms=[laser, stray]), ["telemetry"])
    tree = check_urdf(text)
    assert "root Link: base_link has 5 child(ren)" in tree
    assert "beacon" not in text
    origin = _joints(text)["laser_joint"].find("origin")
    assert origin is not None
    assert origin.get("xyz") == "0.2 0 0.1"
    assert float(str(origin.get("rpy")).split()[2]) == pytest.approx(math.pi)


def _telemetry(at: float, speed: float) -> Any:
    wheels = SimpleNamespace(**dict.fromkeys(FOUR_WHEELS, speed))
    return SimpleNamespace(wheels=wheels, voltage=25.0, timestamp=at)


# (timestamp s, each wheel's speed m/s) -> (angle rad, speed rad/s) of the front left wheel
# after it, with a 0.1 m radius.
JOINT_ROWS = [
    ("still", [(10.0, 0.0), (10.02, 0.0)], (0.0, 0.0)),
    ("one step", [(10.0, 0.5), (10.02, 0.5)], (0.1, 5.0)),
    ("backwards", [(10.0, -0.5), (10.02, -0.5), (10.04, -0.5)], (-0.2, -5.0)),
    ("a gap adds nothing", [(10.0, 0.5), (10.0 + JOINT_GAP + 0.1, 0.5)], (0.0, 5.0)),
    ("the same stamp twice", [(10.0, 0.5), (10.0, 0.5)], (0.0, 5.0)),
    ("wraps at pi", [(10.0 + i * 0.02, 1.0) for i in range(17)], (3.2 - math.tau, 10.0)),
]


@pytest.mark.parametrize(
    ("readings", "expected"), [r[1:] for r in JOINT_ROWS], ids=[r[0] for r in JOINT_ROWS]
)
def test_joint_states_integrate_the_wheel_speeds(
    readings: list[tuple[float, float]], expected: tuple[float, float]
) -> None:
    size = Geometry(track_width=0.5, wheelbase=0.4, wheel_radius=0.1)
    translator = Translator(Ros2Options(), ["telemetry"], geometry=size)
    assert "joint_states" in translator.topics
    states = []
    for at, speed in readings:
        for key, message in translator.messages("telemetry", _telemetry(at, speed)):
            if key == "joint_states":
                states.append(message)
    assert len(states) == len(readings)  # one per telemetry frame
    last = states[-1]
    assert list(last.name) == [f"{w}_wheel_joint" for w in FOUR_WHEELS]
    assert last.position[0] == pytest.approx(expected[0], abs=1e-9)
    assert last.velocity[0] == pytest.approx(expected[1])


def test_no_geometry_no_joint_states() -> None:
    translator = Translator(Ros2Options(), ["telemetry"])
    assert translator.topics == ("battery_state",)


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"track_width": 0.0, "wheelbase": 0.4, "wheel_radius": 0.1}, ValueError),
        ({"track_width": 0.5, "wheelbase": math.nan, "wheel_radius": 0.1}, ValueError),
        ({"track_width": 0.5, "wheelbase": 0.4, "wheel_radius": "0.1"}, TypeError),
        (
            {"track_width": 0.5, "wheelbase": 0.4, "wheel_radius": 0.1, "wheels": ("left",)},
            ValueError,
        ),
        (
            {
                "track_width": 0.5,
                "wheelbase": 0.4,
                "wheel_radius": 0.1,
                "wheels": ("front_rear_left",),
            },
            ValueError,
        ),
    ],
)
def test_a_bad_size_is_refused(kwargs: dict[str, Any], error: type[Exception]) -> None:
    with pytest.raises(error):
        Geometry(**kwargs)
