"""rosbag2 recordings (:mod:`chassis_sdk.recording.ros2`): the simulators recorded over
real ptys, the files read back by two independent bag readers and by the SDK's own.

* ``rosbags`` (``rosbags.highlevel.AnyReader``, which opens a bare ``.mcap``: no bag
  directory or ``metadata.yaml`` needed) and mcap-ros2-support (its ``DecoderFactory``
  under ``mcap``'s reader) each decode every message from the file's own schemas;
* what rosbag2 itself checks is there: profile ``ros2``, ``ros2msg`` schemas that are
  the definitions rosbag2 writes and declare rosbags' Jazzy types, ``cdr`` messages, QoS YAML that parses (``/tf_static``
  latched), ``topic_type_hash`` equal to rosbags' REP 2011 hash;
* the session's raw bytes come back through ``capture.read_capture``, ``replay`` and
  ``export`` exactly as from a Foxglove recording of the same session.
"""

from __future__ import annotations

import asyncio
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

from chassis_sdk import Board, Chassis, ImuSample, Telemetry
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.recording import capture, open_recording, ros2_types
from chassis_sdk.recording.ros2 import Ros2Recording, rosbag
from chassis_sdk.recording.ros2_types import StaticTransform
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import ROOT, cli, one_line
from .support.helpers import kill_while_recording
from .support.msgdefs import jazzy_differences

pytestmark = pytest.mark.timeout(60)

STORE = get_typestore(Stores.ROS2_JAZZY)
#: The SDK's message classes by their ROS names.
TYPES = {ros2_types.ros_name(cls): cls for cls in ros2_types._all_types()}
G = 9.80665
RAW = "std_msgs/msg/UInt8MultiArray"


def mcap_summary(path: Path) -> tuple[Any, dict[str, Any], dict[str, dict[str, str]]]:
    """The header; topic -> (channel, schema, message count); the metadata records."""
    with path.open("rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None
        assert summary.statistics is not None
        counts = summary.statistics.channel_message_counts
        channels = {
            ch.topic: (ch, summary.schemas[ch.schema_id], counts.get(cid, 0))
            for cid, ch in summary.channels.items()
        }
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return header, channels, metadata


def with_rosbags(path: Path) -> tuple[dict[str, Any], list[tuple[str, int, Any]]]:
    """topic -> rosbags connection; every message (topic, log time ns, decoded)."""
    with AnyReader([path], default_typestore=STORE) as reader:
        connections = {c.topic: c for c in reader.connections}
        messages = [
            (c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()
        ]
    return connections, messages


def of(messages: list[tuple[str, int, Any]], topic: str) -> list[Any]:
    return [m for t, _, m in messages if t == topic]


def qos(channel: Any) -> dict[str, Any]:
    profiles = YAML(typ="safe").load(channel.metadata["offered_qos_profiles"])
    assert isinstance(profiles, list)
    assert len(profiles) == 1
    profile: dict[str, Any] = profiles[0]
    return profile


def check_rosbag2_shape(path: Path, expected: dict[str, str]) -> dict[str, Any]:
    """What rosbag2's MCAP storage reads, for each ``topic: type`` expected."""
    header, channels, metadata = mcap_summary(path)
    assert header.profile == "ros2"
    assert header.library.startswith("chassis_sdk ")
    assert set(channels) == set(expected), sorted(channels)
    for topic, type_name in expected.items():
        channel, schema, _ = channels[topic]
        assert schema.name == type_name
        assert schema.encoding == "ros2msg"
        assert jazzy_differences(schema.data.decode(), type_name) == []
        assert schema.data.decode() == ros2_types.definition(TYPES[type_name])
        assert channel.message_encoding == "cdr"
        assert channel.metadata["topic_type_hash"] == STORE.hash_rihs01(type_name)
        profile = qos(channel)
        assert profile["history"] == "keep_last"
        assert profile["reliability"] == "reliable"
        assert profile["depth"] >= 1
        for duration in ("deadline", "lifespan", "liveliness_lease_duration"):
            assert set(profile[duration]) == {"sec", "nsec"}
        assert profile["liveliness"] == "automatic"
        assert profile["avoid_ros_namespace_conventions"] is False
    return {"channels": channels, "metadata": metadata}


def every_message_decodes_with_mcap_ros2(path: Path) -> dict[str, list[Any]]:
    """topic -> messages, decoded by mcap-ros2-support (its decoder for ``cdr`` with a
    ``ros2msg`` schema; what ``mcap_ros2.reader.read_ros2_messages`` did, not deprecated)."""
    found: dict[str, list[Any]] = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _, decoded in reader.iter_decoded_messages():
            assert schema is not None
            assert type(decoded).__name__ == schema.name.rsplit("/", 1)[-1]
            found.setdefault(channel.topic, []).append(decoded)
    return found


async def drive(robot: Chassis, frames: int) -> list[Telemetry]:
    seen = []
    async for t in robot.telemetry():
        await robot.set_velocity(0.3, 0.5)
        seen.append(t)
        if len(seen) == frames:
            break
    return seen


# --- a chassis, recorded as a rosbag2 file and as a Foxglove file at once --------------------


@pytest.mark.integration
async def test_a_chassis_session_is_a_rosbag2_file_both_readers_open(tmp_path: Path) -> None:
    bag, fox = tmp_path / "run.mcap", tmp_path / "fox.mcap"
    async with ChassisSimulator() as sim:
        port = sim.port
        robot = Chassis(port, record=rosbag(bag, namespace="robot1"))
        assert robot.recording == bag
        assert not bag.exists()  # nothing opens before connect
        foxglove = open_recording(fox, robot)  # the same session, as Foxglove's MCAP
        started = time.time()
        try:
            async with robot:
                seen = await drive(robot, 60)
        finally:
            foxglove.close()
        ended = time.time()

    raw = "/robot1/chassis_sdk/chassis/raw"
    shape = check_rosbag2_shape(
        bag,
        {
            "/robot1/odom": "nav_msgs/msg/Odometry",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/robot1/battery_state": "sensor_msgs/msg/BatteryState",
            f"{raw}/rx": RAW,
            f"{raw}/tx": RAW,
        },
    )
    channels = shape["channels"]
    assert qos(channels["/robot1/odom"][0])["durability"] == "volatile"
    info = shape["metadata"]["chassis_sdk"]
    assert (info["device"], info["port"], info["baudrate"]) == ("chassis", port, "115200")
    assert "rosbag2" not in shape["metadata"]  # rosbag2 would read the QoS as v8 then

    # rosbags: every message, from the file's own definitions.
    connections, messages = with_rosbags(bag)
    assert connections["/robot1/odom"].msgtype == "nav_msgs/msg/Odometry"
    assert [c.ext.offered_qos_profiles[0].depth for c in [connections["/tf"]]] == [100]
    telemetry = [m for _, m in capture.decode_capture(bag, "chassis") if isinstance(m, Telemetry)]
    odometry = of(messages, "/robot1/odom")
    assert len(telemetry) >= len(seen) >= 60
    assert len(odometry) == len(telemetry)  # one sample per telemetry frame, none missed
    assert len(of(messages, "/tf")) == len(odometry)
    log_times = [t for topic, t, _ in messages if topic == "/robot1/odom"]
    assert log_times == sorted(log_times)
    span = (log_times[-1] - log_times[0]) / 1e9
    assert 0.8 * 50 * span <= len(odometry) - 1 <= 1.2 * 50 * span  # 50 Hz
    for topic, log_time, _ in messages:
        assert started - 1 <= log_time / 1e9 <= ended + 1, topic
    # Under a namespace the frames carry its prefix: robots share one /tf tree.
    for odom in odometry:
        assert (odom.header.frame_id, odom.child_frame_id) == ("robot1/odom", "robot1/base_link")
        assert started - 1 <= odom.header.stamp.sec + odom.header.stamp.nanosec / 1e9 <= ended + 1
        for matrix in (odom.pose.covariance, odom.twist.covariance):
            assert all(v > 0 for v in matrix.reshape(6, 6).diagonal())
    assert odometry[-1].pose.pose.position.x > 0.05  # it drove forward and turned
    assert odometry[-1].pose.pose.orientation.z > 0.01
    transform = of(messages, "/tf")[-1].transforms[0]
    assert (transform.header.frame_id, transform.child_frame_id) == (
        "robot1/odom",
        "robot1/base_link",
    )
    assert transform.transform.translation.x == odometry[-1].pose.pose.position.x
    battery = of(messages, "/robot1/battery_state")
    assert 1 <= len(battery) <= math.ceil(span) + 1  # 1 Hz from 50 Hz telemetry
    assert battery[0].voltage == pytest.approx(telemetry[0].voltage, abs=1e-5)
    assert math.isnan(battery[0].current)
    assert battery[0].header.frame_id == "robot1/base_link"

    # mcap-ros2-support: the same messages, decoded by another implementation.
    decoded = every_message_decodes_with_mcap_ros2(bag)
    assert {topic: len(msgs) for topic, msgs in decoded.items()} == {
        topic: count for topic, (_, _, count) in channels.items() if count
    }
    assert [o.pose.pose.position.x for o in decoded["/robot1/odom"]] == [
        o.pose.pose.position.x for o in odometry
    ]

    # The SDK reads it back as it reads the Foxglove recording of the same session.
    assert [d for _, d in capture.read_capture(bag)] == [d for _, d in capture.read_capture(fox)]
    sent = [d for _, d in capture.read_capture(bag, sent=True)]
    assert sent == [d for _, d in capture.read_capture(fox, sent=True)]
    commands = [c for _, c in capture.decode_capture(bag, "chassis", commands=True)]
    assert len(commands) == len(sent) == channels[f"{raw}/tx"][2]
    assert commands[-1] == DriveVelocity(0, 0.0)  # the zero of close() is in it
    assert capture.mcap_metadata(bag)["device"] == "chassis"
    # What the application saw, in order, then the robot coming to rest after the final
    # zero (a recording goes on until it is still: issue 44, item 6).
    seqs = [t.seq for t in telemetry]
    first = seqs.index(seen[0].seq)
    assert seqs[first : first + len(seen)] == [t.seq for t in seen]
    assert telemetry[-1].linear == 0.0

    code, out, err = await cli("replay", str(bag), "--json")
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert sum(line["type"] == "Telemetry" for line in lines) == len(telemetry)
    code, out, err = await cli("export", str(bag), "--csv", str(tmp_path / "csv"))
    assert code == 0, err
    with (tmp_path / "csv" / "telemetry.csv").open() as f:
        assert len(list(csv.DictReader(f))) == len(telemetry)
    # Reading it back needs no cyclonedds (a laptop, an aarch64 box without the extra).
    without = (
        "import sys; sys.modules['cyclonedds'] = None\n"
        "from chassis_sdk.recording import capture\n"
        f"print(sum(len(d) for _, d in capture.read_capture({str(bag)!r})))"
    )
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", without, stdout=asyncio.subprocess.PIPE, cwd=ROOT
    )
    out_bytes, _ = await proc.communicate()
    assert proc.returncode == 0
    assert int(out_bytes) == sum(len(d) for _, d in capture.read_capture(fox))


@pytest.mark.integration
async def test_a_battery_model_gives_the_recorded_battery_state_its_percentage(
    tmp_path: Path,
) -> None:
    from chassis_sdk import BatteryModel

    bag = tmp_path / "charge.mcap"
    model = BatteryModel("lifepo4", cells=8, warmup=0.2, min_readings=1)
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, record=rosbag(bag), battery=model) as robot,
    ):
        await drive(robot, 150)  # 3 s: three BatteryState at 1 Hz, the later ones known
        charge = robot.battery_percentage
    _, messages = with_rosbags(bag)
    battery = of(messages, "/battery_state")
    assert len(battery) >= 2
    known = [b.percentage for b in battery if not math.isnan(b.percentage)]
    assert known, [b.percentage for b in battery]
    assert charge is not None
    assert known[-1] == pytest.approx(charge / 100, abs=0.05)


# --- a board: its IMU, and the static transform to it -------------------------------------


@pytest.mark.integration
async def test_a_board_session_has_imu_and_a_latched_static_transform(tmp_path: Path) -> None:
    bag = tmp_path / "board.mcap"
    started = time.time()
    async with BoardSimulator() as sim, Board(sim.port, record=rosbag(str(bag))) as board:
        n = 0
        async for _ in board.imu():
            n += 1
            if n == 100:
                break
    shape = check_rosbag2_shape(
        bag,
        {
            "/odom": "nav_msgs/msg/Odometry",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/tf_static": "tf2_msgs/msg/TFMessage",
            "/battery_state": "sensor_msgs/msg/BatteryState",
            "/imu/data_raw": "sensor_msgs/msg/Imu",
            "/chassis_sdk/board/raw/rx": RAW,
            "/chassis_sdk/board/raw/tx": RAW,
        },
    )
    static_qos = qos(shape["channels"]["/tf_static"][0])
    assert (static_qos["durability"], static_qos["depth"]) == ("transient_local", 1)
    _, messages = with_rosbags(bag)
    (static,) = of(messages, "/tf_static")
    (transform,) = static.transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("base_link", "imu_link")
    t, q = transform.transform.translation, transform.transform.rotation
    assert (t.x, t.y, t.z, q.x, q.y, q.z, q.w) == (0, 0, 0, 0, 0, 0, 1)
    assert transform.header.stamp.sec >= int(started) - 1
    samples = [m for _, m in capture.decode_capture(bag, "board") if isinstance(m, ImuSample)]
    imu = of(messages, "/imu/data_raw")
    assert len(imu) == len(samples) >= 100
    for msg, sample in zip(imu, samples, strict=True):
        assert msg.header.frame_id == "imu_link"
        a = msg.linear_acceleration
        assert (a.x, a.y, a.z) == (sample.accel.x * G, sample.accel.y * G, sample.accel.z * G)
        assert msg.angular_velocity.z == math.radians(sample.gyro.z)
        assert msg.orientation_covariance[0] == -1  # no orientation estimate
    decoded = every_message_decodes_with_mcap_ros2(bag)
    assert len(decoded["/imu/data_raw"]) == len(imu)
    assert capture.mcap_metadata(bag)["device"] == "board"


@pytest.mark.integration
async def test_the_options_name_the_frames_and_the_static_transforms(tmp_path: Path) -> None:
    bag = tmp_path / "options.mcap"
    laser = StaticTransform("chassis", "laser", x=0.1, z=0.2, yaw=math.pi)
    chosen = rosbag(
        bag,
        namespace="/fleet/r2/",
        frame_id="r2_odom",
        child_frame_id="chassis",
        imu_frame_id="imu",
        static_transforms=[laser],
        pose_covariance=(1, 1, 1, 1, 1, 1),
        metadata={"operator": "test"},
        frame_prefix="",  # the frames exactly as named (by default: "fleet/r2/" first)
    )
    assert chosen.namespace == "/fleet/r2"
    async with BoardSimulator() as sim, Board(sim.port, record=chosen) as board:
        async for _ in board.imu():
            break
        async for _ in board.velocity():
            break
    _, channels, metadata = mcap_summary(bag)
    assert metadata["chassis_sdk"]["operator"] == "test"
    _, messages = with_rosbags(bag)
    (static,) = of(messages, "/tf_static")
    assert [(t.header.frame_id, t.child_frame_id) for t in static.transforms] == [
        ("chassis", "laser")
    ]
    assert static.transforms[0].transform.rotation.z == pytest.approx(1.0)
    odom = of(messages, "/fleet/r2/odom")[0]
    assert (odom.header.frame_id, odom.child_frame_id) == ("r2_odom", "chassis")
    assert list(odom.pose.covariance.reshape(6, 6).diagonal()) == [1.0] * 6
    assert of(messages, "/fleet/r2/imu/data_raw")[0].header.frame_id == "imu"
    assert "/fleet/r2/chassis_sdk/board/raw/rx" in channels


# --- choosing it: refused early, with clear errors ------------------------------------------


def test_a_bad_choice_is_refused_before_anything_opens(tmp_path: Path) -> None:
    good = tmp_path / "run.mcap"
    (tmp_path / "dir.mcap").mkdir()
    bad: list[tuple[type[Exception], str, dict[str, Any], Any]] = [
        (ValueError, "MCAP file", {}, tmp_path / "run.jsonl"),
        (ValueError, "directory", {}, tmp_path / "dir.mcap"),
        (TypeError, "file path", {}, 3),
        (ValueError, "file path", {}, ""),
        (TypeError, "namespace", {"namespace": 3}, good),
        (ValueError, "namespace", {"namespace": "robot 1"}, good),
        (ValueError, "digit", {"namespace": "1robot"}, good),
        (ValueError, "frame", {"frame_id": "/odom"}, good),
        (ValueError, "frame", {"child_frame_id": ""}, good),
        (TypeError, "StaticTransform", {"static_transforms": [("base_link", "imu")]}, good),
        (ValueError, "parent", {"static_transforms": [StaticTransform("/a", "b")]}, good),
        (ValueError, "x", {"static_transforms": [StaticTransform("a", "b", x=math.nan)]}, good),
        (ValueError, "pose_covariance", {"pose_covariance": (0,) * 6}, good),
        (ValueError, "twist_covariance", {"twist_covariance": (1,) * 5}, good),
        (ValueError, "flush_interval", {"flush_interval": 0}, good),
        (TypeError, "metadata", {"metadata": {"a": 1}}, good),
    ]
    for error, says, options, path in bad:
        with pytest.raises(error, match=says):
            rosbag(path, **options)
    robot = Chassis("/dev/null")
    with pytest.raises(ValueError, match="MCAP file"):
        open_recording(tmp_path / "run.jsonl", robot, ros2=True)
    with pytest.raises(TypeError, match="not both"):
        Ros2Recording(good, robot, options=rosbag(good), namespace="x")
    assert [p.name for p in tmp_path.iterdir()] == ["dir.mcap"]  # made above: nothing else


# --- the CLI ------------------------------------------------------------------------------


@pytest.mark.integration
async def test_cli_records_a_rosbag2_file_passively(tmp_path: Path) -> None:
    bag = tmp_path / "cli.mcap"
    async with ChassisSimulator() as sim:
        code, out, err = await cli(
            "record", sim.port, str(bag), "--ros2", "--namespace", "r1", "--seconds", "1.5"
        )
        assert code == 0, err
        assert not sim.firmware.received  # a viewer never writes
    check_rosbag2_shape(
        bag,
        {
            "/r1/odom": "nav_msgs/msg/Odometry",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/r1/battery_state": "sensor_msgs/msg/BatteryState",
            "/r1/chassis_sdk/chassis/raw/rx": RAW,
            "/r1/chassis_sdk/chassis/raw/tx": RAW,
        },
    )
    _, messages = with_rosbags(bag)
    telemetry = [m for _, m in capture.decode_capture(bag, "chassis") if isinstance(m, Telemetry)]
    assert len(telemetry) >= 50
    assert len(of(messages, "/r1/odom")) == len(telemetry)
    assert of(messages, "/r1/chassis_sdk/chassis/raw/tx") == []
    assert len(every_message_decodes_with_mcap_ros2(bag)["/r1/odom"]) == len(telemetry)
    code, out, err = await cli("replay", str(bag))
    assert code == 0, err
    assert "Telemetry: " in out


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "says"),
    [
        pytest.param(["out.jsonl", "--ros2"], "name it FILE.mcap", id="ros2-not-mcap"),
        pytest.param(["out.mcap", "--namespace", "r1"], "--namespace is for --ros2", id="ns-alone"),
        pytest.param(["out.mcap", "--ros2", "--namespace", "1r"], "digit", id="bad-namespace"),
    ],
)
async def test_cli_refuses_a_bad_ros2_choice_in_one_line_before_the_port_opens(
    tmp_path: Path, args: list[str], says: str
) -> None:
    # No such port: the refusal comes first, so it is the one line said.
    code, _, err = await cli("record", str(tmp_path / "no-such-port"), *args)
    assert code == 1
    assert says in one_line(err)
    assert list(tmp_path.iterdir()) == []


# --- a hard kill loses at most the flush interval ------------------------------------------


@pytest.mark.integration
async def test_a_hard_kill_leaves_a_bag_readable_up_to_the_last_second(tmp_path: Path) -> None:
    bag = tmp_path / "killed.mcap"
    async with ChassisSimulator() as sim:
        await kill_while_recording(sim.port, str(bag), "rosbag(sys.argv[2])", ROOT)
    # 100 frames took 2 s; chunks are flushed every second: at least one is whole.
    frames = [m for _, m in capture.decode_capture(bag, "chassis") if isinstance(m, Telemetry)]
    assert len(frames) >= 40
    assert capture.mcap_metadata(bag)["device"] == "chassis"
    code, out, err = await cli("replay", str(bag))
    assert code == 0, err
    assert "Telemetry: " in out


@pytest.mark.integration
async def test_record_takes_any_target_that_opens_its_own_recorder(tmp_path: Path) -> None:
    """The core knows no format: a ``record`` target is a path that opens its recorder."""

    class Stub:
        closed = 0

        def close(self) -> None:
            self.closed += 1

    opened: list[tuple[Any, Stub]] = []

    class Target:
        def __fspath__(self) -> str:
            return str(tmp_path / "any.name")

        def open_recorder(self, device: Any) -> Stub:
            opened.append((device, Stub()))
            return opened[-1][1]

    async with ChassisSimulator() as sim:
        robot = Chassis(sim.port, record=Target())
        assert robot.recording == tmp_path / "any.name"
        assert opened == []  # opened as the device connects, not before
        async with robot:
            ((device, stub),) = opened
            assert device is robot
            assert stub.closed == 0
        assert stub.closed == 1
