"""The ROS 2 messages of :mod:`chassis_sdk.recording.ros2_types`, held against an
independent implementation of ROS 2's type system and CDR: ``rosbags`` (its Jazzy type
store, which carries the .msg files of ROS 2 Jazzy).

* every class's definition is what rosbag2 writes (the .msg files as they are, comments
  and defaults kept), declares rosbags' Jazzy types, and its REP 2011 type hash is
  rosbags' own;
* each converter's message, serialised by Cyclone DDS, is byte for byte what rosbags
  serialises for the same message built here from rosbags' classes, the expected field
  values worked out here from the inputs (unit conversions, the yaw quaternion, the
  covariance diagonals), never read back from ours;
* random finite readings survive serialise -> rosbags' deserialise;
* the helpers refuse what they must (covariance) and convert time at its edges.
"""

from __future__ import annotations

import math
import struct
import time
from types import SimpleNamespace
from typing import Any, cast

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from chassis_sdk import BatteryModel, Chassis
from chassis_sdk.recording import ros2_types as r
from chassis_sdk.sim import ChassisSimulator, ChassisSpec, PackSpec

from .support.msgdefs import jazzy_differences

pytestmark = pytest.mark.timeout(60)

STORE = get_typestore(Stores.ROS2_JAZZY)
TYPES = r._all_types()
G = 9.80665
#: An epoch whose nanoseconds are exact in binary too (stamp() multiplies by 1e9: at
#: today's epochs a product is a multiple of 256 ns), so the expected stamp is exact.
EPOCH = 1_700_000_000.5
STAMP = (1_700_000_000, 500_000_000)


def rb(name: str) -> Any:
    """A rosbags message class by its ROS name."""
    return STORE.types[name]


def cdr(message: Any, name: str) -> bytes:
    return bytes(STORE.serialize_cdr(message, name))


def rb_header(frame_id: str, stamp: tuple[int, int] = STAMP) -> Any:
    return rb("std_msgs/msg/Header")(
        stamp=rb("builtin_interfaces/msg/Time")(sec=stamp[0], nanosec=stamp[1]), frame_id=frame_id
    )


def rb_vector(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
    return rb("geometry_msgs/msg/Vector3")(x=x, y=y, z=z)


def rb_yaw(heading: float) -> Any:
    return rb("geometry_msgs/msg/Quaternion")(
        x=0.0, y=0.0, z=math.sin(heading / 2), w=math.cos(heading / 2)
    )


def diagonal(values: tuple[float, ...]) -> Any:
    return np.diag(np.array(values, dtype=np.float64)).reshape(36)


def raw(data: bytes) -> Any:
    """``std_msgs/UInt8MultiArray`` of ``data`` (its IDL annotations are not types)."""
    return r.UInt8MultiArray(data=cast(Any, data))


def f32(value: float) -> float:
    result: float = struct.unpack("<f", struct.pack("<f", value))[0]
    return result


# --- definitions and type hashes ------------------------------------------------------------


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: r.ros_name(c))
def test_the_definition_declares_rosbags_types_and_the_type_hash_is_rosbags_own(
    cls: type,
) -> None:
    name = r.ros_name(cls)
    assert jazzy_differences(r.definition(cls), name) == []
    assert r.type_hash(cls) == STORE.hash_rihs01(name)


#: ``geometry_msgs/msg/Quaternion.msg`` of ROS 2 Jazzy, as ``ros2 interface show`` and
#: rosbag2 give it: its comment, its fields and their defaults.
QUATERNION_MSG = """\
# This represents an orientation in free space in quaternion form.

float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""


def test_the_definition_is_the_msg_file_as_it_is_as_rosbag2_writes_it() -> None:
    # rosbag2 (rosbag2_cpp's LocalMessageDefinitionSource) stores the .msg file's text
    # as it is: ``float64 w 1``, not ``float64 w``, and the comments.
    assert r.definition(r.Quaternion) == QUATERNION_MSG
    constants = r.definition(r.BatteryState)
    assert "uint8 POWER_SUPPLY_TECHNOLOGY_LIFE = 4" in constants
    assert "# Constants are chosen to match the enums in the linux kernel" in constants


def test_the_definition_puts_each_used_type_after_it_as_rosbag2_does() -> None:
    # Each type the file uses, sorted by name (its std::set), depth first, each once,
    # after "\n", 80 "=" and "MSG: pkg/Type" as the file names it.
    text = r.definition(r.Odometry)
    sections = text.split("\n" + "=" * 80 + "\n")
    assert [s.split("\n", 1)[0] for s in sections[1:]] == [
        "MSG: geometry_msgs/PoseWithCovariance",
        "MSG: geometry_msgs/Pose",
        "MSG: geometry_msgs/Point",
        "MSG: geometry_msgs/Quaternion",
        "MSG: geometry_msgs/TwistWithCovariance",
        "MSG: geometry_msgs/Twist",
        "MSG: geometry_msgs/Vector3",
        "MSG: std_msgs/Header",
        "MSG: builtin_interfaces/Time",
    ]
    assert sections[4] == "MSG: geometry_msgs/Quaternion\n" + QUATERNION_MSG
    assert sections[0].startswith("# This represents an estimate of a position and velocity")
    assert "\ngeometry_msgs/PoseWithCovariance pose\n" in sections[0]


def test_every_type_the_topics_use_is_checked() -> None:
    for spec in r.TOPICS.values():
        assert spec.type in TYPES
    assert r.UInt8MultiArray in TYPES  # the recorder's raw bytes


# --- converters: the same bytes as rosbags' serialiser -----------------------------------------

ODOM = SimpleNamespace(x=1.5, y=-0.25, heading=0.75, linear=0.3, angular=-0.2, timestamp=0.0)


def test_odometry_is_rosbags_bytes() -> None:
    ours = r.odometry_message(ODOM, EPOCH, frame_id="odom", child_frame_id="base_link")
    theirs = rb("nav_msgs/msg/Odometry")(
        header=rb_header("odom"),
        child_frame_id="base_link",
        pose=rb("geometry_msgs/msg/PoseWithCovariance")(
            pose=rb("geometry_msgs/msg/Pose")(
                position=rb("geometry_msgs/msg/Point")(x=1.5, y=-0.25, z=0.0),
                orientation=rb_yaw(0.75),
            ),
            covariance=diagonal((0.001, 0.001, 1e6, 1e6, 1e6, 0.01)),
        ),
        twist=rb("geometry_msgs/msg/TwistWithCovariance")(
            twist=rb("geometry_msgs/msg/Twist")(linear=rb_vector(x=0.3), angular=rb_vector(z=-0.2)),
            covariance=diagonal((0.001, 0.001, 1e6, 1e6, 1e6, 0.01)),
        ),
    )
    assert ours.serialize() == cdr(theirs, "nav_msgs/msg/Odometry")
    assert ours.serialize()[:4] == b"\x00\x01\x00\x00"  # plain CDR, little endian


@pytest.mark.parametrize(
    ("stamps", "published", "repeated"),
    [
        ((1.0, 1.05, 1.1), [1.0, 1.05, 1.1], 0),
        # two frames of one read share its receive time: the second gives nothing
        ((1.0, 1.0, 1.05), [1.0, 1.05], 1),
        ((1.0, 1.05, 1.02, 1.1), [1.0, 1.05, 1.1], 1),  # never backwards either
    ],
)
def test_odometry_stamps_only_go_forward(
    stamps: tuple[float, ...], published: list[float], repeated: int
) -> None:
    translator = r.Translator(r.Ros2Options(), ["odometry"], forward_only=True)
    sent: list[float] = []
    for t in stamps:
        out = translator.messages("odometry", SimpleNamespace(**{**vars(ODOM), "timestamp": t}))
        if out:
            assert [key for key, _ in out] == ["odom", "tf"]
            sent.append(t)
    assert sent == published
    assert translator.repeated_odometry == repeated
    recorder = r.Translator(r.Ros2Options(), ["odometry"])  # a recording keeps them all
    assert all(
        recorder.messages("odometry", SimpleNamespace(**{**vars(ODOM), "timestamp": t}))
        for t in stamps
    )


def test_odometry_takes_given_covariances() -> None:
    pose = r.covariance((1, 2, 3, 4, 5, 6))
    twist = r.covariance((0.5, 0, 0, 0, 0, 0.5))
    ours = r.odometry_message(ODOM, EPOCH, pose_covariance=pose, twist_covariance=twist)
    decoded: Any = STORE.deserialize_cdr(ours.serialize(), "nav_msgs/msg/Odometry")
    assert list(decoded.pose.covariance) == list(diagonal((1, 2, 3, 4, 5, 6)))
    assert list(decoded.twist.covariance) == list(diagonal((0.5, 0, 0, 0, 0, 0.5)))


def test_transform_is_rosbags_bytes() -> None:
    ours = r.transform_message(ODOM, EPOCH, frame_id="odom", child_frame_id="base_link")
    theirs = rb("tf2_msgs/msg/TFMessage")(
        transforms=[
            rb("geometry_msgs/msg/TransformStamped")(
                header=rb_header("odom"),
                child_frame_id="base_link",
                transform=rb("geometry_msgs/msg/Transform")(
                    translation=rb_vector(1.5, -0.25, 0.0), rotation=rb_yaw(0.75)
                ),
            )
        ]
    )
    assert ours.serialize() == cdr(theirs, "tf2_msgs/msg/TFMessage")


def test_static_transforms_are_rosbags_bytes() -> None:
    ours = r.static_transforms_message(
        [
            r.StaticTransform("base_link", "imu_link"),
            r.StaticTransform("base_link", "laser", 0.1, 0, 0.2, 3.0),
        ],
        EPOCH,
    )
    stamped = rb("geometry_msgs/msg/TransformStamped")
    transform = rb("geometry_msgs/msg/Transform")
    theirs = rb("tf2_msgs/msg/TFMessage")(
        transforms=[
            stamped(
                header=rb_header("base_link"),
                child_frame_id="imu_link",
                transform=transform(translation=rb_vector(), rotation=rb_yaw(0.0)),
            ),
            stamped(
                header=rb_header("base_link"),
                child_frame_id="laser",
                transform=transform(translation=rb_vector(0.1, 0.0, 0.2), rotation=rb_yaw(3.0)),
            ),
        ]
    )
    assert ours.serialize() == cdr(theirs, "tf2_msgs/msg/TFMessage")


def test_battery_is_rosbags_bytes_with_nan_for_what_is_not_measured() -> None:
    ours = r.battery_message(24.5, EPOCH, frame_id="base_link")
    nan = math.nan
    theirs = rb("sensor_msgs/msg/BatteryState")(
        header=rb_header("base_link"),
        voltage=24.5, temperature=nan, current=nan, charge=nan, capacity=nan,
        design_capacity=nan, percentage=nan,
        power_supply_status=0, power_supply_health=0, power_supply_technology=0,
        present=True,
        cell_voltage=np.array([], dtype=np.float32),
        cell_temperature=np.array([], dtype=np.float32),
        location="", serial_number="",
    )  # fmt: skip
    assert ours.serialize() == cdr(theirs, "sensor_msgs/msg/BatteryState")
    with_percentage = r.battery_message(24.5, EPOCH, percentage=0.5).serialize()
    decoded: Any = STORE.deserialize_cdr(with_percentage, "sensor_msgs/msg/BatteryState")
    assert decoded.percentage == 0.5
    assert math.isnan(decoded.current)


def rb_battery(voltage: float, **fields: Any) -> Any:
    nan = math.nan
    values: dict[str, Any] = {
        "header": rb_header("base_link"), "voltage": voltage, "temperature": nan,
        "current": nan, "charge": nan, "capacity": nan, "design_capacity": nan,
        "percentage": nan, "power_supply_status": 0, "power_supply_health": 0,
        "power_supply_technology": 0, "present": True,
        "cell_voltage": np.array([], dtype=np.float32),
        "cell_temperature": np.array([], dtype=np.float32),
        "location": "", "serial_number": "",
    }  # fmt: skip
    return rb("sensor_msgs/msg/BatteryState")(**{**values, **fields})


def warm_model(chemistry: str, voltage: float, **options: Any) -> BatteryModel:
    model = BatteryModel(chemistry, warmup=0.0, min_readings=1, **options)  # type: ignore[arg-type]
    model.update(voltage, now=0.0)
    return model


def test_a_battery_model_gives_percentage_0_to_1_technology_and_capacity() -> None:
    # li-ion 7S at 3.82 V a cell is 50 % (the curve's own point): percentage 0.5.
    model = warm_model("li-ion", 7 * 3.82, cells=7, capacity_ah=2.5)
    ours = r.charge_message(26.7, EPOCH, model, frame_id="base_link")
    theirs = rb_battery(26.7, percentage=0.5, power_supply_technology=2, design_capacity=2.5)
    assert ours.serialize() == cdr(theirs, "sensor_msgs/msg/BatteryState")
    # LiFePO4 at 3.30 V a cell is 70 %: technology LIFE (4); no capacity: NaN.
    model = warm_model("lifepo4", 8 * 3.30, cells=8)
    decoded: Any = STORE.deserialize_cdr(
        r.charge_message(26.4, EPOCH, model).serialize(), "sensor_msgs/msg/BatteryState"
    )
    assert decoded.percentage == pytest.approx(0.70, abs=1e-6)
    assert decoded.power_supply_technology == 4
    assert math.isnan(decoded.design_capacity)
    assert decoded.power_supply_health == 0  # health is not charge
    # Lead-acid and a custom curve name no technology (UNKNOWN).
    lead = warm_model("lead-acid", 12 * 2.01, cells=12)
    assert r.charge_message(24.1, EPOCH, lead).power_supply_technology == 0
    custom = warm_model("li-ion", 7.0, cells=2, curve=[(3.0, 0.0), (4.0, 100.0)])
    message = r.charge_message(7.0, EPOCH, custom)
    assert message.power_supply_technology == 0
    assert message.percentage == pytest.approx(0.5)


def test_without_a_model_or_before_it_knows_the_percentage_is_nan() -> None:
    assert r.charge_message(24.5, EPOCH, None, frame_id="base_link").serialize() == cdr(
        rb_battery(24.5), "sensor_msgs/msg/BatteryState"
    )
    cold = BatteryModel("li-ion", cells=7)  # warm-up 3 s, 5 readings
    cold.update(26.7, now=0.0)
    assert cold.percentage is None
    ours = r.charge_message(26.7, EPOCH, cold, frame_id="base_link")
    theirs = rb_battery(26.7, power_supply_technology=2)
    assert ours.serialize() == cdr(theirs, "sensor_msgs/msg/BatteryState")


def test_the_translator_reads_the_model_for_each_battery_state() -> None:
    model = BatteryModel("li-ion", cells=7, warmup=0.0, min_readings=1)
    options = r.Ros2Options()
    board = r.Translator(options, ["imu", "battery"], battery=model)
    reading = SimpleNamespace(voltage=7 * 3.82, timestamp=time.monotonic())
    ((key, before),) = board.messages("battery", reading)
    assert key == "battery_state"
    assert math.isnan(before.percentage)
    model.update(reading.voltage, now=0.0)
    ((_, after),) = board.messages("battery", reading)
    assert after.percentage == pytest.approx(0.5)
    assert after.header.frame_id == "base_link"
    assert math.isnan(
        r.Translator(options, ["battery"]).messages("battery", reading)[0][1].percentage
    )
    with pytest.raises(TypeError, match="BatteryModel"):
        r.Translator(options, ["battery"], battery=50.0)  # type: ignore[arg-type]


@pytest.mark.integration
async def test_battery_state_of_a_chassis_on_the_simulated_pack() -> None:
    # Through a real pty: the chassis's 0x81 voltage at 1 Hz, the percentage its model
    # makes of it, against the pack's true charge.
    pack = PackSpec("li-ion", cells=7, charge=40.0)
    model = BatteryModel("li-ion", cells=7, warmup=0.5, min_readings=3)
    async with (
        ChassisSimulator(ChassisSpec(pack=pack)) as sim,
        Chassis(sim.port, battery=model) as robot,
    ):
        translator = r.Translator(r.Ros2Options(), ["telemetry"], battery=robot.battery_model)
        states = []
        async for t in robot.telemetry():
            states += [m for _, m in translator.messages("telemetry", t)]
            if robot.battery_percentage is not None and len(states) >= 2:
                break
        truth = sim.firmware.battery_charge
    assert math.isnan(states[0].percentage)  # the first, before the model knew
    last = states[-1]
    assert truth is not None
    assert abs(last.percentage * 100 - truth) <= 3
    assert 0.0 <= last.percentage <= 1.0
    assert last.voltage == pytest.approx(7 * 3.79, abs=0.3)  # 40 % on the curve, 0.1 V
    decoded: Any = STORE.deserialize_cdr(last.serialize(), "sensor_msgs/msg/BatteryState")
    assert decoded.percentage == pytest.approx(last.percentage)


def test_imu_is_rosbags_bytes_in_si_units_without_orientation() -> None:
    sample = SimpleNamespace(
        accel=SimpleNamespace(x=0.5, y=-1.0, z=1.0),
        gyro=SimpleNamespace(x=90.0, y=-45.0, z=180.0),
        mag=SimpleNamespace(x=1.0, y=2.0, z=3.0),
        timestamp=0.0,
    )
    ours = r.imu_message(sample, EPOCH, frame_id="imu_link")
    nine = np.zeros(9, dtype=np.float64)
    unknown = nine.copy()
    unknown[0] = -1.0  # sensor_msgs/Imu: no orientation estimate
    theirs = rb("sensor_msgs/msg/Imu")(
        header=rb_header("imu_link"),
        orientation=rb("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.0, w=0.0),
        orientation_covariance=unknown,
        angular_velocity=rb_vector(math.pi / 2, -math.pi / 4, math.pi),
        angular_velocity_covariance=nine,
        linear_acceleration=rb_vector(0.5 * G, -1.0 * G, 1.0 * G),
        linear_acceleration_covariance=nine,
    )
    assert ours.serialize() == cdr(theirs, "sensor_msgs/msg/Imu")


def test_diagnostics_is_rosbags_bytes() -> None:
    ours = r.diagnostics_message(
        EPOCH,
        name="chassis_sdk: chassis",
        hardware_id="/dev/ttyUSB0",
        level=r.DIAGNOSTIC_WARN,
        message="battery low",
        values=[("voltage", "21.3"), ("faults", "")],
    )
    kv = rb("diagnostic_msgs/msg/KeyValue")
    theirs = rb("diagnostic_msgs/msg/DiagnosticArray")(
        header=rb_header(""),
        status=[
            rb("diagnostic_msgs/msg/DiagnosticStatus")(
                level=1,
                name="chassis_sdk: chassis",
                message="battery low",
                hardware_id="/dev/ttyUSB0",
                values=[kv(key="voltage", value="21.3"), kv(key="faults", value="")],
            )
        ],
    )
    assert ours.serialize() == cdr(theirs, "diagnostic_msgs/msg/DiagnosticArray")


def test_raw_bytes_are_rosbags_bytes() -> None:
    data = bytes(range(256)) + b"\xaa\x55"
    ours = raw(data)
    theirs = rb("std_msgs/msg/UInt8MultiArray")(
        layout=rb("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0),
        data=np.frombuffer(data, dtype=np.uint8),
    )
    assert ours.serialize() == cdr(theirs, "std_msgs/msg/UInt8MultiArray")
    back: Any = r.UInt8MultiArray.deserialize(ours.serialize())
    assert bytes(back.data) == data


def test_the_commands_the_bridge_reads_decode_from_rosbags_bytes() -> None:
    twist = rb("geometry_msgs/msg/Twist")(linear=rb_vector(x=0.4), angular=rb_vector(z=-1.25))
    ours = r.Twist.deserialize(cdr(twist, "geometry_msgs/msg/Twist"))
    assert (ours.linear.x, ours.angular.z) == (0.4, -1.25)
    stamped = rb("geometry_msgs/msg/TwistStamped")(header=rb_header("base_link"), twist=twist)
    decoded = r.TwistStamped.deserialize(cdr(stamped, "geometry_msgs/msg/TwistStamped"))
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == STAMP
    assert decoded.twist.linear.x == 0.4
    on = r.Bool.deserialize(cdr(rb("std_msgs/msg/Bool")(data=True), "std_msgs/msg/Bool"))
    assert on.data is True


# --- random readings: serialise, rosbags deserialises them the same ------------------------------

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
epochs = st.floats(min_value=0, max_value=2**31 - 2, allow_nan=False)
frames = st.text(
    alphabet=st.characters(codec="utf-8", exclude_characters="\x00"), min_size=1, max_size=30
)


@settings(max_examples=60, deadline=None)
@given(
    x=finite, y=finite, heading=finite, linear=finite, angular=finite, epoch=epochs, frame=frames
)
def test_random_odometry_round_trips_through_rosbags(
    x: float, y: float, heading: float, linear: float, angular: float, epoch: float, frame: str
) -> None:
    sample = SimpleNamespace(x=x, y=y, heading=heading, linear=linear, angular=angular)
    decoded: Any = STORE.deserialize_cdr(
        r.odometry_message(sample, epoch, frame_id=frame).serialize(), "nav_msgs/msg/Odometry"
    )
    ns = round(epoch * 1e9)
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == divmod(ns, 10**9)
    assert decoded.header.frame_id == frame
    pose = decoded.pose.pose
    assert (pose.position.x, pose.position.y, pose.position.z) == (x, y, 0.0)
    q = pose.orientation
    assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, math.sin(heading / 2), math.cos(heading / 2))
    assert (decoded.twist.twist.linear.x, decoded.twist.twist.angular.z) == (linear, angular)
    assert all(v > 0 for v in np.diag(decoded.pose.covariance.reshape(6, 6)))


@settings(max_examples=60, deadline=None)
@given(
    accel=st.tuples(finite, finite, finite), gyro=st.tuples(finite, finite, finite), epoch=epochs
)
def test_random_imu_round_trips_through_rosbags(
    accel: tuple[float, float, float], gyro: tuple[float, float, float], epoch: float
) -> None:
    sample = SimpleNamespace(
        accel=SimpleNamespace(x=accel[0], y=accel[1], z=accel[2]),
        gyro=SimpleNamespace(x=gyro[0], y=gyro[1], z=gyro[2]),
    )
    decoded: Any = STORE.deserialize_cdr(
        r.imu_message(sample, epoch).serialize(), "sensor_msgs/msg/Imu"
    )
    a, w = decoded.linear_acceleration, decoded.angular_velocity
    assert (a.x, a.y, a.z) == tuple(v * G for v in accel)
    assert (w.x, w.y, w.z) == tuple(math.radians(v) for v in gyro)
    assert decoded.header.frame_id == "imu_link"


@settings(max_examples=60, deadline=None)
@given(voltage=st.floats(width=32, allow_nan=False, allow_infinity=False), epoch=epochs)
def test_random_battery_round_trips_through_rosbags(voltage: float, epoch: float) -> None:
    decoded: Any = STORE.deserialize_cdr(
        r.battery_message(voltage, epoch).serialize(), "sensor_msgs/msg/BatteryState"
    )
    assert decoded.voltage == f32(voltage)
    assert decoded.present is True


@settings(max_examples=40, deadline=None)
@given(
    level=st.sampled_from(
        [r.DIAGNOSTIC_OK, r.DIAGNOSTIC_WARN, r.DIAGNOSTIC_ERROR, r.DIAGNOSTIC_STALE]
    ),
    text=frames,
    values=st.lists(st.tuples(frames, frames), max_size=5),
)
def test_random_diagnostics_round_trip_through_rosbags(
    level: int, text: str, values: list[tuple[str, str]]
) -> None:
    message = r.diagnostics_message(EPOCH, name=text, hardware_id=text, level=level, message=text,
                                    values=values)  # fmt: skip
    decoded: Any = STORE.deserialize_cdr(message.serialize(), "diagnostic_msgs/msg/DiagnosticArray")
    (status,) = decoded.status
    assert (status.level, status.name, status.message, status.hardware_id) == (
        level,
        text,
        text,
        text,
    )
    assert [(kv.key, kv.value) for kv in status.values] == values


@settings(max_examples=40, deadline=None)
@given(data=st.binary(max_size=600))
def test_random_raw_bytes_round_trip_through_rosbags(data: bytes) -> None:
    decoded: Any = STORE.deserialize_cdr(raw(data).serialize(), "std_msgs/msg/UInt8MultiArray")
    assert bytes(decoded.data) == data


# --- the helpers ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "diagonal",
    [
        pytest.param((0.0,) * 6, id="all-zero"),
        pytest.param((0.1, 0.1, -1.0, 0.1, 0.1, 0.1), id="negative"),
        pytest.param((0.1, math.nan, 0.1, 0.1, 0.1, 0.1), id="nan"),
        pytest.param((0.1, 0.1, math.inf, 0.1, 0.1, 0.1), id="infinite"),
        pytest.param((0.1,) * 5, id="five"),
        pytest.param((0.1,) * 36, id="a-whole-matrix"),
    ],
)
def test_covariance_refuses_what_a_reader_would_misread(diagonal: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="covariance"):
        r.covariance(diagonal)


def test_covariance_puts_the_variances_on_the_diagonal() -> None:
    matrix = r.covariance((1, 0, 0, 0, 0, 2))
    assert len(matrix) == 36
    assert (matrix[0], matrix[35]) == (1.0, 2.0)
    assert sum(matrix) == 3.0
    with pytest.raises(ValueError, match="pose_covariance"):
        r.covariance((0,) * 6, "pose_covariance")


@pytest.mark.parametrize(
    ("epoch", "expected"),
    [
        pytest.param(0.0, (0, 0), id="zero"),
        pytest.param(1.5, (1, 500_000_000), id="half"),
        pytest.param(1.9999999999, (2, 0), id="rounds-up-into-the-next-second"),
        pytest.param(2.0000000004, (2, 0), id="rounds-down"),
        pytest.param(-0.25, (-1, 750_000_000), id="before-the-epoch"),
        pytest.param(2_147_483_647.0, (2_147_483_647, 0), id="int32-max"),
        pytest.param(EPOCH, STAMP, id="today"),
    ],
)
def test_stamp_splits_seconds_and_nanoseconds(epoch: float, expected: tuple[int, int]) -> None:
    t = r.stamp(epoch)
    assert (t.sec, t.nanosec) == expected
    assert 0 <= t.nanosec < 1_000_000_000
    decoded: Any = STORE.deserialize_cdr(t.serialize(), "builtin_interfaces/msg/Time")
    assert (decoded.sec, decoded.nanosec) == expected


@pytest.mark.timing
def test_wall_time_of_a_monotonic_reading() -> None:
    ago = time.monotonic() - 2.0
    assert r.wall_time(ago, now=1000.0) == pytest.approx(998.0, abs=0.05)
    assert abs(r.wall_time(time.monotonic()) - time.time()) < 0.05
    # No clock reading (0.0, a message decoded without one): now.
    assert r.wall_time(0.0, now=1234.5) == 1234.5
    assert r.wall_time(-1.0, now=1234.5) == 1234.5
    assert abs(r.wall_time(0.0) - time.time()) < 0.05


# --- reading the raw bytes back without cyclonedds ---------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    data=st.binary(max_size=300),
    labels=st.lists(st.text(max_size=12), max_size=3),
    offset=st.integers(0, 2**32 - 1),
    big_endian=st.booleans(),
)
def test_the_struct_reader_of_uint8multiarray_agrees_with_rosbags(
    data: bytes, labels: list[str], offset: int, big_endian: bool
) -> None:
    """``capture.uint8_multiarray_data`` (what replay, export and plot read a rosbag2
    file with, no cyclonedds needed) against rosbags' serialiser, any layout."""
    from chassis_sdk.recording.capture import uint8_multiarray_data

    dims = [
        rb("std_msgs/msg/MultiArrayDimension")(label=label, size=i, stride=2 * i)
        for i, label in enumerate(labels)
    ]
    layout = rb("std_msgs/msg/MultiArrayLayout")(dim=dims, data_offset=offset)
    message = rb("std_msgs/msg/UInt8MultiArray")(
        layout=layout, data=np.frombuffer(data, dtype=np.uint8)
    )
    name = "std_msgs/msg/UInt8MultiArray"
    encoded = bytes(STORE.serialize_cdr(message, name, little_endian=not big_endian))
    assert uint8_multiarray_data(encoded) == data
    if not big_endian:  # and what the recorder writes (cyclonedds, little-endian)
        assert uint8_multiarray_data(raw(data).serialize()) == data
    for cut in range(4, len(encoded)):  # every proper prefix is refused, not misread
        with pytest.raises(ValueError, match="cut short"):
            uint8_multiarray_data(encoded[:cut])


def test_the_struct_reader_refuses_what_is_not_cdr() -> None:
    from chassis_sdk.recording.capture import uint8_multiarray_data

    for bad in (b"", b"\x00", b"\x01\x00\x00\x00" + bytes(8), b"\x00\x07\x00\x00" + bytes(8)):
        with pytest.raises(ValueError, match="encapsulation"):
            uint8_multiarray_data(bad)


@pytest.mark.parametrize(
    ("namespace", "prefix", "expected"),
    [
        ("", None, "odom"),  # no namespace: the frames as named
        ("r1", None, "r1/odom"),  # a namespace's tokens: robots share one /tf tree
        ("/fleet/r2/", None, "fleet/r2/odom"),
        ("r1", "", "odom"),  # asked for none
        ("", "robot_a/", "robot_a/odom"),
        ("r1", "custom_", "custom_odom"),
    ],
)
def test_frames_carry_the_namespaces_prefix_unless_told_otherwise(
    namespace: str, prefix: str | None, expected: str
) -> None:
    options = r.Ros2Options(namespace=namespace, frame_prefix=prefix)
    assert options.frame("odom") == expected
    static = options.static_for(["imu"])
    assert [(st.parent, st.child) for st in static] == [
        (options.frame("base_link"), options.frame("imu_link"))
    ]


@pytest.mark.parametrize(
    ("prefix", "error"), [("/r1/", ValueError), ("r 1/", ValueError), (3, TypeError)]
)
def test_a_bad_frame_prefix_is_refused(prefix: object, error: type[Exception]) -> None:
    with pytest.raises(error, match="frame_prefix"):
        r.Ros2Options(namespace="r1", frame_prefix=prefix)  # type: ignore[arg-type]
