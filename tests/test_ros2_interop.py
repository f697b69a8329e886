"""The ROS 2 bridge against an independent DDS stack: eProsima Fast DDS (the middleware
of ROS 2's default RMW), 2.9 (Debian 12's) and 3.1 (Debian 13's, what Kilted and Lyrical
run; stock settings, type propagation on), built from an IDL of our own in ROS 2's DDS
shape (tests/ros2_peer), over RTPS on UDP (no shared memory). The peer plays teleop
(publishing ``cmd_vel``) and Nav2 (subscribing ``odom`` and ``/tf``). Every test that
talks to a peer runs against each (``[fastdds2]``, ``[fastdds3]``).

What this proves: the bridge interoperates with Fast DDS 2.9 and 3.1 over RTPS with
ROS 2's naming, types and QoS, and tells the graph its node as rmw does (what
``ros2 node list`` and ``ros2 node info`` read). It does not prove rmw_zenoh or
services.

Every test runs in a network namespace of its own whose only interface is loopback.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
from collections.abc import AsyncIterator
from typing import Any
from xml.etree import ElementTree

import anyio
import pytest

from chassis_sdk import Board, Chassis
from chassis_sdk.core.geometry import FOUR_WHEELS
from chassis_sdk.devices.chassis.messages import DriveVelocity
from chassis_sdk.integrations.ros2 import Ros2Bridge
from chassis_sdk.integrations.ros2.dds import Discovery
from chassis_sdk.recording.ros2_types import DEFAULT_POSE_COVARIANCE, wall_time
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import CLI, ROOT, cli, one_line
from .support.dds_peer import FAST_DDS, FAST_DDS_IDS, Event, start_peer
from .support.ros2 import bridged as running
from .support.ros2 import drives, until
from .support.urdf import check_urdf

pytestmark = [
    pytest.mark.integration,
    pytest.mark.netns,
    pytest.mark.timeout(90),
    pytest.mark.usefixtures("fast_dds"),  # the peers' Fast DDS (tests/conftest.py)
]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """Every test that talks to a peer (marked ``ros2``) runs against each Fast DDS."""
    if metafunc.definition.get_closest_marker("ros2") is not None:
        metafunc.parametrize("fast_dds", FAST_DDS, indirect=True, ids=FAST_DDS_IDS)


#: How long one command holds (the bridge's default, diff_drive_controller's).
TIMEOUT = 0.5


@contextlib.asynccontextmanager
async def bridged(device: Any, **options: Any) -> AsyncIterator[Ros2Bridge]:
    options.setdefault("discovery", Discovery(domain_id=0))
    async with running(device, **options) as bridge:
        yield bridge


def _sample(e: Event) -> bool:
    return e.get("event") == "sample"


@pytest.mark.ros2
@pytest.mark.timing
async def test_teleop_moves_the_robot_at_once_and_a_silent_writer_stops_it(fast_dds: int) -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot) as bridge,
    ):
        args = ("pub", "twist", "rt/cmd_vel", "--rate", "20", "--count", "10", "--hold", "3")
        async with await start_peer(*args, "--linear", "0.3", "--angular", "0.2") as teleop:
            first = await teleop.wait_for("published", 15.0)
            await until(lambda: any(c.linear_mm == 300 for _, c in drives(sim)), 2.0)
            moved = next(t for t, c in drives(sim) if c.linear_mm == 300)
            # First command -> motion. A Fast DDS 3 writer matches the bridge's reader
            # some 50-100 ms before the bridge's reader knows of the writer, and what it
            # writes meanwhile is lost (issue 43, not yet mitigated): its first command
            # or two at 20 Hz.
            assert wall_time(moved) - first["t"] < (0.1 if fast_dds == 2 else 0.25)
            last = await teleop.wait_for(lambda e: e.get("i") == 9, 5.0)
            # Alive and silent: the robot's measured velocity is zero within the deadman
            # plus 0.5 s of the last command.
            await until(
                lambda: (
                    (t := robot.latest_telemetry) is not None
                    and t.linear == 0.0
                    and wall_time(t.timestamp) > last["t"]
                ),
                TIMEOUT + 1.0,
            )
            telemetry = robot.latest_telemetry
            assert telemetry is not None
            assert wall_time(telemetry.timestamp) - last["t"] < TIMEOUT + 0.5
            assert teleop.returncode is None  # the writer was still there, silent
        assert bridge.commands >= 5
        assert bridge.refused == 0


@pytest.mark.ros2
@pytest.mark.timing
async def test_the_robot_stops_within_200_ms_of_the_publisher_leaving() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, command_timeout=5.0) as bridge,
    ):
        # A 5 s deadman: only the writer's leaving can stop the robot this soon.
        args = ("pub", "twist", "rt/cmd_vel", "--rate", "20", "--count", "10", "--linear", "0.25")
        async with await start_peer(*args) as teleop:
            gone = await teleop.wait_for("deleting_writer", 15.0)
            await until(lambda: drives(sim)[-1][1] == DriveVelocity(0, 0.0), 1.0)
            stopped = drives(sim)[-1][0]
            assert any(c.linear_mm == 250 for _, c in drives(sim))
            assert wall_time(stopped) - gone["t"] < 0.2
        assert bridge.writer_gone_stops == 1


@pytest.mark.ros2
@pytest.mark.timing
async def test_twist_stamped_with_stamped() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, stamped=True) as bridge,
    ):
        args = ("pub", "twist_stamped", "rt/cmd_vel", "--rate", "20", "--count", "10")
        async with await start_peer(*args, "--linear", "0.2") as teleop:
            await teleop.wait_for("writer_deleted", 15.0)
            await until(lambda: any(c.linear_mm == 200 for _, c in drives(sim)), 1.0)
        assert bridge.refused == 0


@pytest.mark.ros2
@pytest.mark.slow
@pytest.mark.timing
async def test_nav2_gets_odometry_at_the_telemetry_rate_with_frames_stamps_and_covariance() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot) as _bridge,
    ):
        await robot.set_velocity(0.2, 0.1, duration=10.0)  # a moving pose
        async with (
            await start_peer("sub", "odometry", "rt/odom", "--duration", "2") as nav2,
            await start_peer("sub", "tf", "rt/tf", "--count", "20") as tf,
        ):
            await nav2.wait_for("matched", 15.0)
            start = len(nav2.events)
            first = await nav2.wait_for(_sample, 5.0, since=start)
            await nav2.wait_for("done", 10.0)
            samples = [e for e in nav2.events[start:] if _sample(e)]
            span = samples[-1]["t"] - first["t"]
            rate = (len(samples) - 1) / span
            assert 45 < rate < 55, rate  # the chassis's 50 Hz telemetry
            lags = sorted(
                e["t"] - (e["stamp"]["sec"] + e["stamp"]["nanosec"] * 1e-9)
                for e in samples
                if e["t"] > first["t"] + 0.5  # past the first heartbeats after matching
            )
            assert lags[0] >= 0, lags  # stamps are the wall clock of the reading
            assert lags[len(lags) // 2] < 0.01, lags  # stamp to receipt: the median
            assert lags[int(len(lags) * 0.95)] < 0.05, lags
            last = samples[-1]
            assert (last["frame_id"], last["child_frame_id"]) == ("odom", "base_link")
            diagonal = [last["pose_covariance"][i * 7] for i in range(6)]
            assert diagonal == pytest.approx(list(DEFAULT_POSE_COVARIANCE))
            assert last["linear"]["x"] == pytest.approx(0.2, abs=0.02)
            assert math.hypot(last["position"]["x"], last["position"]["y"]) > 0.05
            await tf.wait_for("done", 10.0)
            transform = tf.samples[-1]["transforms"][0]
            assert (transform["frame_id"], transform["child_frame_id"]) == ("odom", "base_link")


@pytest.mark.ros2
async def test_tf_static_reaches_a_late_joiner_and_imu_and_battery_flow() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board, bridged(board) as _bridge:
        async with await start_peer("sub", "imu", "rt/imu/data_raw", "--count", "5") as imu:
            await imu.wait_for("done", 15.0)
            sample = imu.samples[-1]
            assert sample["frame_id"] == "imu_link"
            assert sample["orientation_covariance"][0] == -1.0
        battery_args = ("sub", "battery", "rt/battery_state", "--count", "1")
        async with await start_peer(*battery_args) as battery:
            await battery.wait_for("done", 15.0)
            got = battery.samples[-1]
            assert got["voltage"] == pytest.approx(sim.firmware.battery_voltage, abs=0.2)
            assert got["percentage"] is None  # NaN: unknown
        # Joins seconds after the bridge published /tf_static: the latched sample.
        late_args = ("sub", "tf", "rt/tf_static", "--transient-local", "--count", "1")
        async with await start_peer(*late_args) as late:
            await late.wait_for("done", 15.0)
            (transform,) = late.samples[-1]["transforms"]
            assert (transform["frame_id"], transform["child_frame_id"]) == ("base_link", "imu_link")


@pytest.mark.ros2
async def test_ros_discovery_info_names_the_node_and_exactly_the_endpoints_peers_discover() -> None:
    # What `ros2 node list` and `ros2 node info` read (rmw_dds_common's graph cache): the
    # node on `ros_discovery_info`, latched, its gid the participant's GUID, and the GIDs
    # of exactly the readers and writers that DDS discovery finds on that participant.
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, namespace="robot1"),
    ):
        args = ("sub", "graph", "ros_discovery_info", "--transient-local", "--count", "1")
        async with await start_peer(*args) as peer:
            sample = await peer.wait_for("sample", 15.0)
            (node,) = sample["nodes"]
            assert (node["namespace"], node["name"]) == ("/robot1", "chassis_bridge")
            gid = sample["gid"]
            await peer.wait_for(lambda e: e["event"] == "participant" and e["guid"] == gid, 10.0)
            prefix = gid[:24]  # the GUID prefix every entity of the participant shares

            def found(entity: str) -> dict[str, str]:
                return {
                    e["guid"]: e["topic"]
                    for e in peer.named("endpoint")
                    if e["entity"] == entity
                    and e["status"] == "discovered"
                    and e["guid"].startswith(prefix)
                    and e["topic"] != "ros_discovery_info"
                }

            readers, writers = set(node["readers"]), set(node["writers"])
            await until(lambda: readers <= found("reader").keys(), 10.0)
            await until(lambda: writers <= found("writer").keys(), 10.0)
            assert found("reader").keys() == readers
            assert found("writer").keys() == writers
            assert sorted(found("reader").values()) == [
                "rt/robot1/cmd_vel",
                "rt/robot1/emergency_stop",
            ]
            assert sorted(found("writer").values()) == [
                "rt/diagnostics",
                "rt/robot1/battery_state",
                "rt/robot1/joint_states",
                "rt/robot1/odom",
                "rt/robot1/robot_description",
                "rt/tf",
            ]


@pytest.mark.ros2
async def test_rviz_draws_the_robot_from_its_robot_description_and_joint_states() -> None:
    # What robot_state_publisher and RViz read: the latched URDF (checked by urdfdom,
    # ROS's own parser) with the chassis's size and four wheels, and the wheels'
    # joint_states at the telemetry rate, turning as the robot drives.
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, namespace="r1"),
    ):
        info = await robot.get_chassis_info()
        args = ("sub", "string", "rt/r1/robot_description", "--transient-local", "--count", "1")
        async with await start_peer(*args) as described:
            await described.wait_for("done", 15.0)
            (sample,) = described.samples
        tree = await asyncio.to_thread(check_urdf, sample["data"])
        assert "root Link: r1/base_link has 4 child(ren)" in tree
        joints = {j.get("name"): j for j in ElementTree.fromstring(sample["data"]).iter("joint")}
        origin = joints["front_left_wheel_joint"].find("origin")
        assert origin is not None
        assert origin.get("xyz") == f"{info.wheelbase / 2:g} {info.track_width / 2:g} 0"
        async with anyio.create_task_group() as tg:

            async def drive() -> None:
                while True:  # within the deadman
                    await robot.set_velocity(0.3, 0.0)
                    await asyncio.sleep(0.1)

            tg.start_soon(drive)
            await until(lambda: (t := robot.latest_telemetry) is not None and t.linear > 0.29)
            states = ("sub", "joint_state", "rt/r1/joint_states", "--count", "50")
            async with await start_peer(*states) as peer:
                await peer.wait_for("done", 15.0)
            tg.cancel_scope.cancel()
        stamps = [s["stamp"]["sec"] + s["stamp"]["nanosec"] / 1e9 for s in peer.samples]
        assert 0.8 / 50 <= (stamps[-1] - stamps[0]) / 49 <= 1.25 / 50  # the telemetry's 50 Hz
        last = peer.samples[-1]
        assert last["name"] == [f"{w}_wheel_joint" for w in FOUR_WHEELS]
        radius = info.wheel_diameter / 2
        assert last["velocity"] == pytest.approx([0.3 / radius] * 4, rel=0.05)
        angles = [s["position"][0] for s in peer.samples]  # in [-pi, pi]: unwrapped here
        turned = sum(math.remainder(b - a, math.tau) for a, b in itertools.pairwise(angles))
        assert turned == pytest.approx(0.3 / radius * (stamps[-1] - stamps[0]), rel=0.1)


@pytest.mark.slow
@pytest.mark.ros2
async def test_two_namespaced_bridges_in_one_domain_each_drive_only_their_robot() -> None:
    # Two robots on one graph (`--namespace r1`, `--namespace r2`): each one's cmd_vel
    # moves it alone, and their frames are prefixed, so one /tf tree holds both.
    async with (
        ChassisSimulator() as sim1,
        ChassisSimulator() as sim2,
        Chassis(sim1.port) as robot1,
        Chassis(sim2.port) as robot2,
        bridged(robot1, namespace="r1"),
        bridged(robot2, namespace="r2"),
    ):
        args = ("pub", "twist", "rt/r2/cmd_vel", "--rate", "20", "--count", "40")
        async with await start_peer(*args, "--linear", "0.25") as teleop:
            await teleop.wait_for("published", 15.0)
            await until(lambda: any(c.linear_mm == 250 for _, c in drives(sim2)), 3.0)
            await teleop.wait_for("acked", 10.0)
        assert [c for _, c in drives(sim1) if c.linear_mm != 0] == []  # r1 never moved
        tf_args = ("sub", "tf", "rt/tf", "--count", "40")
        async with await start_peer(*tf_args) as tf:
            await tf.wait_for("done", 15.0)
            pairs = {
                (t["frame_id"], t["child_frame_id"]) for e in tf.samples for t in e["transforms"]
            }
        assert pairs == {("r1/odom", "r1/base_link"), ("r2/odom", "r2/base_link")}
        odom_args = ("sub", "odometry", "rt/r1/odom", "--count", "1")
        async with await start_peer(*odom_args) as odom:
            await odom.wait_for("done", 15.0)
            (got,) = odom.samples
            assert (got["frame_id"], got["child_frame_id"]) == ("r1/odom", "r1/base_link")
        graph_args = ("sub", "graph", "ros_discovery_info", "--transient-local", "--count", "2")
        async with await start_peer(*graph_args) as graph:
            await graph.wait_for("done", 15.0)
            nodes = sorted((n["namespace"], n["name"]) for e in graph.samples for n in e["nodes"])
        assert nodes == [("/r1", "chassis_bridge"), ("/r2", "chassis_bridge")]


@pytest.mark.slow
@pytest.mark.ros2
async def test_qos_that_must_not_match_does_not() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, bridged(robot) as _bridge:
        # A BEST_EFFORT writer cannot feed the RELIABLE emergency_stop reader.
        args = ("pub", "bool", "rt/emergency_stop", "--best-effort", "--wait-match", "3")
        async with await start_peer(*args) as estop:
            assert await estop.wait(15.0) == 3
            assert estop.named("no_match")
        # A BEST_EFFORT reader takes a RELIABLE writer's odometry.
        odom_args = ("sub", "odometry", "rt/odom", "--best-effort", "--count", "3")
        async with await start_peer(*odom_args) as viewer:
            await viewer.wait_for("done", 15.0)
            assert len(viewer.samples) == 3
        assert not sim.firmware.software_estop


@pytest.mark.ros2
@pytest.mark.timing
async def test_unicast_only_discovery_with_static_peers() -> None:
    # No multicast at all in this namespace: discovery only by unicast.
    await anyio.run_process(["ip", "route", "del", "224.0.0.0/4", "dev", "lo"])
    await anyio.run_process(["ip", "link", "set", "lo", "multicast", "off"])
    discovery = Discovery(domain_id=0, range="LOCALHOST")
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, discovery=discovery) as _bridge,
    ):
        args = ("pub", "twist", "rt/cmd_vel", "--unicast", "--rate", "20", "--count", "5")
        async with await start_peer(*args, "--linear", "0.15") as teleop:
            started = await teleop.wait_for("started", 15.0)
            matched = await teleop.wait_for("matched", 5.0)
            # Tens of milliseconds as a rule (benchmarks/ros2.py measures it); bounded
            # here by Fast DDS's announcement period, should its first ones be missed.
            assert matched["t"] - started["t"] < 3.5
            await until(lambda: any(c.linear_mm == 150 for _, c in drives(sim)), 3.0)


@pytest.mark.ros2
async def test_a_non_finite_command_from_the_peer_is_refused() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, bridged(robot) as bridge:
        # Streamed until one is refused: the bridge's reader may learn of the writer a
        # while after the writer matched it, and gets nothing written before that.
        args = ("pub", "twist", "rt/cmd_vel", "--rate", "20", "--count", "200", "--linear", "nan")
        async with await start_peer(*args):
            await until(lambda: bridge.refused >= 1, 10.0)
        assert all(c.linear_mm == 0 for _, c in drives(sim))


@pytest.mark.ros2
@pytest.mark.slow
async def test_chassis_sdk_ros2_puts_a_simulated_chassis_on_the_graph_and_stops_it_at_the_end() -> (
    None
):
    async with ChassisSimulator() as sim:
        args = ("ros2", sim.port, "--namespace", "robot1", "--seconds", "8")
        bridge = await asyncio.create_subprocess_exec(
            *CLI, *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=ROOT
        )  # fmt: skip
        try:
            assert bridge.stdout is not None
            async with asyncio.timeout(20):
                line = (await bridge.stdout.readline()).decode()
            assert "onto ROS 2 domain 0 under /robot1" in line, line
            # A teleop streams (20 Hz for 3 s): its writer can match the bridge's reader
            # a while before the bridge's reader knows of it (more so under load), and
            # a volatile reader gets nothing written before that.
            teleop_args = ("pub", "twist", "rt/robot1/cmd_vel", "--rate", "20", "--count", "60")
            async with (
                await start_peer("sub", "odometry", "rt/robot1/odom", "--count", "5") as nav2,
                await start_peer(*teleop_args, "--linear", "0.3", "--hold", "10"),
            ):
                await nav2.wait_for("done", 15.0)
                last = nav2.samples[-1]
                assert (last["frame_id"], last["child_frame_id"]) == (
                    "robot1/odom",
                    "robot1/base_link",
                )
                await until(lambda: any(c.linear_mm == 300 for _, c in drives(sim)), 5.0)
                async with asyncio.timeout(15):
                    out, err = await bridge.communicate()  # --seconds ran out
            assert bridge.returncode == 0, err.decode()
            assert "bridge ended: " in out.decode()
            assert "no authentication" in err.decode()  # subnet discovery: it says so
            assert drives(sim)[-1][1] == DriveVelocity(0, 0.0)
        finally:
            if bridge.returncode is None:
                bridge.kill()
                await bridge.wait()


async def test_chassis_sdk_ros2_refuses_bad_options_in_one_line_before_the_port_opens() -> None:
    for args, says in [
        (("--namespace", "robot one"), "namespace"),
        (("--static-peer", "<x>"), "static peer"),
        (("--static-peer", "0"), "static peer"),  # Cyclone would segfault on it
        (("--static-peer", "::1"), "IPv6"),
        (("--frame-prefix", "/r1/"), "frame_prefix"),
    ]:
        code, _out, err = await cli("ros2", "/dev/null/none", *args)
        assert code != 0
        assert says in one_line(err), err
    code, _out, err = await cli("ros2", "/dev/null/none", "--domain-id", "300")
    assert code == 2  # argparse's usage error
    assert "domain_id=300 is out of range" in err


@pytest.mark.ros2
@pytest.mark.slow
async def test_chassis_sdk_ros2_read_only_writes_nothing_to_the_device() -> None:
    async with ChassisSimulator() as sim:
        args = ("ros2", sim.port, "--read-only", "--seconds", "4")
        bridge = await asyncio.create_subprocess_exec(
            *CLI, *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=ROOT
        )  # fmt: skip
        try:
            assert bridge.stdout is not None
            async with asyncio.timeout(20):
                assert "read-only" in (await bridge.stdout.readline()).decode()
            async with (
                await start_peer("sub", "odometry", "rt/odom", "--count", "3") as viewer,
                await start_peer("pub", "twist", "rt/cmd_vel", "--wait-match", "2") as teleop,
            ):
                await viewer.wait_for("done", 15.0)  # it publishes
                assert await teleop.wait(15.0) == 3  # nothing reads cmd_vel
            async with asyncio.timeout(15):
                _out, err = await bridge.communicate()
            assert bridge.returncode == 0, err.decode()
            assert "no authentication" not in err.decode()  # a viewer cannot drive
        finally:
            if bridge.returncode is None:
                bridge.kill()
                await bridge.wait()
    assert len(sim.firmware.received) == 0  # not even the zero at the end
