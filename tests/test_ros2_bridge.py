"""The ROS 2 bridge's behaviour, with a Cyclone DDS participant of the test's own as
the rest of the graph (the wire, against an independent DDS stack, is
test_ros2_interop.py's). Every test that joins DDS runs in a network namespace of its
own whose only interface is loopback (the ``netns`` marker)."""

from __future__ import annotations

import asyncio
import math
import os
import threading
import time
import tty
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager
from typing import Any

import anyio
import pytest
from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from chassis_sdk import Board, Chassis, ConnectionLostError
from chassis_sdk.devices.chassis.messages import DriveVelocity
from chassis_sdk.integrations.ros2 import Ros2Bridge, dds
from chassis_sdk.integrations.ros2.dds import (
    Discovery,
    Participant,
    discovery_from_env,
    fast_dds_3_compatibility,
)
from chassis_sdk.protocol import BoardEncoder, ImuSample, Vector3
from chassis_sdk.recording import ros2_types as m
from chassis_sdk.recording.ros2_types import check_namespace
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.helpers import tasks_of
from .support.ros2 import bridged as running
from .support.ros2 import drives, until

DOMAIN = 17


class Graph:
    """The rest of the ROS 2 graph: a participant with writers and readers."""

    def __init__(self, namespace: str = "") -> None:
        self.dp = DomainParticipant(DOMAIN)
        self.namespace = namespace
        self._topics: dict[str, Topic[Any]] = {}
        #: Readers matched now, by the topic of the writer (one writer a topic; the
        #: listener's count: cyclonedds 0.10 has no getter for it).
        self.readers_of: dict[str, int] = {}

    def topic(self, name: str, tp: type) -> Topic[Any]:
        if name not in self._topics:
            self._topics[name] = Topic(self.dp, name, tp)
        return self._topics[name]

    def writer(self, name: str, tp: type, *, reliable: bool = False) -> DataWriter[Any]:
        qos = Qos(
            Policy.Reliability.Reliable(0) if reliable else Policy.Reliability.BestEffort,
            Policy.History.KeepLast(10),
        )
        self.readers_of[name] = 0
        return DataWriter(self.dp, self.topic(name, tp), qos, _counting(self.readers_of, name))

    def reader(
        self, name: str, tp: type, *, transient: bool = False, depth: int = 1000
    ) -> DataReader[Any]:
        qos = Qos(
            Policy.Reliability.Reliable(0),
            Policy.Durability.TransientLocal if transient else Policy.Durability.Volatile,
            Policy.History.KeepLast(depth),
        )
        return DataReader(self.dp, self.topic(name, tp), qos)


def _counting(counts: dict[str, int], name: str) -> Listener:
    def on_match(_writer: Any, status: Any) -> None:
        counts[name] = int(status.current_count)  # a plain store: no lock needed

    return Listener(on_publication_matched=on_match)  # type: ignore[no-untyped-call]


async def matched(g: Graph, name: str, timeout: float = 5.0) -> None:
    """Until the bridge's reader matched the writer of ``name`` (discovery is done)."""
    await until(lambda: g.readers_of[name] > 0, timeout)


@asynccontextmanager
async def bridged(
    device: Any, **options: Any
) -> AsyncIterator[tuple[Ros2Bridge, anyio.abc.TaskGroup]]:
    """The bridge running for the block, and a task group the block may cancel to end it."""
    options.setdefault("discovery", Discovery(domain_id=DOMAIN))
    async with anyio.create_task_group() as tg, running(device, **options) as bridge:
        yield bridge, tg
        tg.cancel_scope.cancel()


def twist(linear: float, angular: float = 0.0) -> m.Twist:
    return m.Twist(linear=m.Vector3(x=linear), angular=m.Vector3(z=angular))


# --- without DDS: options, names, discovery ------------------------------------------------


@pytest.mark.parametrize(
    ("options", "error"),
    [
        pytest.param({"namespace": "robot one"}, ValueError, id="namespace-space"),
        pytest.param({"namespace": "1robot"}, ValueError, id="namespace-digit"),
        pytest.param({"namespace": 3}, TypeError, id="namespace-type"),
        pytest.param({"command_timeout": 0}, ValueError, id="timeout-zero"),
        pytest.param({"command_timeout": math.nan}, ValueError, id="timeout-nan"),
        pytest.param({"max_linear": -1.0}, ValueError, id="max-linear-negative"),
        pytest.param({"frame_id": "/odom"}, ValueError, id="frame-leading-slash"),
        pytest.param({"child_frame_id": ""}, ValueError, id="frame-empty"),
        pytest.param({"pose_covariance": [0.0] * 6}, ValueError, id="covariance-zero"),
        pytest.param({"twist_covariance": [1.0] * 5}, ValueError, id="covariance-short"),
        pytest.param({"static_transforms": ["base_link"]}, TypeError, id="static-type"),
        pytest.param({"diagnostics_period": -1}, ValueError, id="diagnostics-period"),
    ],
)
def test_bad_options_are_refused_before_anything_is_created(
    options: dict[str, Any], error: type[Exception]
) -> None:
    class NoDevice:
        device_name = "chassis"

    with pytest.raises(error):
        Ros2Bridge(NoDevice(), discovery=Discovery(), **options)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("given", "expected"),
    [("", ""), ("/", ""), ("robot1", "/robot1"), ("/fleet/robot_1/", "/fleet/robot_1")],
)
def test_namespaces(given: str, expected: str) -> None:
    assert check_namespace(given) == expected
    spec = m.TOPICS["odom"]
    assert spec.dds_topic(expected) == f"rt{expected}/odom"
    assert m.TOPICS["tf"].dds_topic(expected) == "rt/tf"  # absolute names stay


@pytest.mark.parametrize(
    ("version", "has_it"),
    [("11.0.1", True), ("11.1.0", True), ("12.0.0", True), ("0.10.5", False), ("0.10.2", False)],
)
def test_the_fast_dds_3_setting_only_where_cyclone_has_it(version: str, has_it: bool) -> None:
    setting = fast_dds_3_compatibility(version)
    assert ("<IgnoreTypeInformation>1.15</IgnoreTypeInformation>" in setting) is has_it
    assert has_it or setting == ""


def test_discovery_follows_ros2s_variables() -> None:
    d = discovery_from_env({})
    assert (d.domain_id, d.range, d.static_peers, d.sets_discovery) == (0, "SUBNET", (), False)
    # No discovery setting: Cyclone's defaults, but always what Fast DDS 3 needs, then
    # the user's CYCLONEDDS_URI (which wins on what it sets). (Cyclone 0.10 has no such
    # setting: `fast_dds_3_compatibility` is empty there, tested above.)
    compat = fast_dds_3_compatibility()
    assert d.config() == f'<CycloneDDS><Domain Id="any">{compat}</Domain></CycloneDDS>'
    assert d.config("file:///etc/cyclone.xml") == f"{d.config()},file:///etc/cyclone.xml"
    d = discovery_from_env({"ROS_DOMAIN_ID": "42", "ROS_AUTOMATIC_DISCOVERY_RANGE": "localhost"})
    assert (d.domain_id, d.range) == (42, "LOCALHOST")
    config = d.config()
    assert config is not None
    assert '<NetworkInterface address="127.0.0.1"/>' in config
    assert "<AllowMulticast>false</AllowMulticast>" in config
    assert "<ParticipantIndex>auto</ParticipantIndex>" in config
    assert '<Peer address="127.0.0.1"/>' in config
    d = discovery_from_env({"ROS_STATIC_PEERS": "10.0.0.2; robot2.local"})
    assert d.static_peers == ("10.0.0.2", "robot2.local")
    config = d.config()
    assert config is not None
    assert "AllowMulticast" not in config
    assert '<Peer address="robot2.local"/>' in config
    assert discovery_from_env({"ROS_LOCALHOST_ONLY": "1"}).range == "LOCALHOST"
    # Explicit options come first.
    d = discovery_from_env({"ROS_DOMAIN_ID": "3"}, domain_id=5, localhost=True, static_peers=[])
    assert (d.domain_id, d.range, d.static_peers) == (5, "LOCALHOST", ())
    for env, words in [
        ({"ROS_DOMAIN_ID": "x"}, "ROS_DOMAIN_ID"),
        ({"ROS_DOMAIN_ID": "300"}, "0 to 232"),
        ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "MARS"}, "ROS_AUTOMATIC_DISCOVERY_RANGE"),
        ({"ROS_STATIC_PEERS": "<evil/>"}, "host name"),
    ]:
        with pytest.raises(ValueError, match=words):
            discovery_from_env(env)


# --- on DDS ------------------------------------------------------------------------------------


@pytest.mark.ros2
@pytest.mark.netns
def test_a_cyclone_older_than_11_says_once_that_fast_dds_3_peers_get_nothing(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # Measured: Cyclone 0.10.2 exchanges nothing with Fast DDS 3.1 (docs/ros2.md).
    monkeypatch.setattr(dds, "_cyclone_version", lambda: "0.10.2")
    dds._warn_old_cyclone.cache_clear()
    for _ in range(2):
        Participant(Discovery(domain_id=77)).close()
    warned = [r.getMessage() for r in caplog.records if "Fast DDS 3" in r.getMessage()]
    assert warned == [
        "cyclonedds 0.10.2 cannot exchange data with Fast DDS 3 (ROS 2 Kilted, Lyrical); "
        "Fast DDS 2 (Jazzy) and Cyclone peers work. Cyclone 11 works with both (docs/ros2.md)"
    ]
    dds._warn_old_cyclone.cache_clear()


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.timing
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_cmd_vel_drives_and_the_deadman_stops_a_silent_writer() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, bridged(robot) as (b, _):
        g = Graph()
        w = g.writer("rt/cmd_vel", m.Twist)
        await matched(g, "rt/cmd_vel")
        w.write(twist(0.3, 0.1))
        await until(lambda: any(c.linear_mm == 300 for _, c in drives(sim)), 2.0)
        moved = next(t for t, c in drives(sim) if c.linear_mm == 300)
        # The writer stays alive and silent: one sample holds command_timeout, then 0
        # (timed by the frames' own arrival, not by when this test noticed them).
        await until(lambda: drives(sim)[-1][1] == DriveVelocity(0, 0.0), 2.0)
        assert 0.45 < drives(sim)[-1][0] - moved < 0.5 + 0.1
        assert b.commands == 1
        assert b.writer_gone_stops == 0


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.timing
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_the_last_writer_leaving_stops_the_robot_at_once() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, command_timeout=5.0) as (b, _),
    ):
        g = Graph()
        w = g.writer("rt/cmd_vel", m.Twist)
        await matched(g, "rt/cmd_vel")
        w.write(twist(0.2))
        await until(lambda: any(c.linear_mm == 200 for _, c in drives(sim)), 2.0)
        left = time.monotonic()
        w.__del__()  # gone: with a 5 s deadman, only its leaving can stop the robot now
        await until(lambda: drives(sim)[-1][1] == DriveVelocity(0, 0.0), 1.0)
        assert time.monotonic() - left < 0.2
        assert b.writer_gone_stops == 1


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_bad_samples_are_refused_and_never_written() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, max_linear=0.4) as (b, _),
    ):
        g = Graph()
        w = g.writer("rt/cmd_vel", m.Twist, reliable=True)
        await matched(g, "rt/cmd_vel")
        for bad in (twist(math.nan), twist(0.1, math.inf), twist(1e300)):
            w.write(bad)
        await until(lambda: b.refused >= 2, 2.0)
        w.write(twist(5.0))  # clamped to max_linear, not refused
        await until(lambda: any(c.linear_mm == 400 for _, c in drives(sim)), 2.0)
        written = {c.linear_mm for _, c in drives(sim)}
        assert written <= {0, 400}, written
        assert b.refused >= 2  # NaN and inf (1e300 is clamped like 5.0)


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_stale_stamped_commands_are_refused() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, stamped=True) as (b, _),
    ):
        g = Graph()
        w = g.writer("rt/cmd_vel", m.TwistStamped, reliable=True)
        await matched(g, "rt/cmd_vel")
        old = m.TwistStamped(header=m.Header(stamp=m.stamp(time.time() - 5.0)), twist=twist(0.3))
        w.write(old)
        await until(lambda: b.refused == 1, 2.0)
        fresh = m.TwistStamped(header=m.Header(stamp=m.stamp(time.time())), twist=twist(0.25))
        w.write(fresh)
        await until(lambda: any(c.linear_mm == 250 for _, c in drives(sim)), 2.0)
        assert not any(c.linear_mm == 300 for _, c in drives(sim))


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.timing
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_a_stamped_command_holds_only_what_is_left_of_the_timeout() -> None:
    """A TwistStamped 0.6 s old, with a 1 s command_timeout, holds 0.4 s (then zero),
    not a full second from when it arrived."""
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, stamped=True, command_timeout=1.0) as (b, _),
    ):
        g = Graph()
        w = g.writer("rt/cmd_vel", m.TwistStamped, reliable=True)
        await matched(g, "rt/cmd_vel")
        aged = m.TwistStamped(header=m.Header(stamp=m.stamp(time.time() - 0.6)), twist=twist(0.3))
        w.write(aged)
        await until(lambda: any(c.linear_mm == 300 for _, c in drives(sim)), 2.0)
        moved = next(t for t, c in drives(sim) if c.linear_mm == 300)
        await until(lambda: drives(sim)[-1][1] == DriveVelocity(0, 0.0), 2.0)
        held = drives(sim)[-1][0] - moved  # timed by the frames' own arrival
        assert 0.3 < held < 0.4 + 0.1, held
        assert b.commands == 1


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_emergency_stop_engages_refuses_velocity_and_releases() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, bridged(robot) as (b, _):
        g = Graph()
        stop = g.writer("rt/emergency_stop", m.Bool, reliable=True)
        cmd = g.writer("rt/cmd_vel", m.Twist)
        await matched(g, "rt/emergency_stop")
        await matched(g, "rt/cmd_vel")
        stop.write(m.Bool(data=True))
        await until(lambda: sim.firmware.software_estop, 2.0)
        cmd.write(twist(0.3))
        await until(lambda: b.refused == 1, 2.0)
        stop.write(m.Bool(data=False))
        await until(lambda: not sim.firmware.software_estop, 2.0)
        # Releasing restarts nothing: cmd_vel streams, so it sends a zero first.
        cmd.write(twist(0.15))
        await until(lambda: b.refused == 2, 2.0)
        assert not any(c.linear_mm for _, c in drives(sim))
        cmd.write(twist(0.0))
        cmd.write(twist(0.15))
        await until(lambda: any(c.linear_mm == 150 for _, c in drives(sim)), 2.0)
        assert not any(c.linear_mm == 300 for _, c in drives(sim))


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_emergency_stop_on_a_device_without_one_blocks_motion_until_released() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board, bridged(board) as (b, _):
        g = Graph()
        stop = g.writer("rt/emergency_stop", m.Bool, reliable=True)
        cmd = g.writer("rt/cmd_vel", m.Twist, reliable=True)
        await matched(g, "rt/emergency_stop")
        await matched(g, "rt/cmd_vel")
        stop.write(m.Bool(data=True))
        await until(lambda: board.motion.blocks == ("SOFTWARE_ESTOP",), 2.0)
        await until(lambda: b.refused == 1, 2.0)  # "has no e-stop": reported
        cmd.write(twist(0.3))
        await until(lambda: b.refused == 2, 2.0)  # blocked by the core
        assert board.commanded_velocity is None
        stop.write(m.Bool(data=False))
        await until(lambda: not board.motion.blocks, 2.0)
        cmd.write(twist(0.0))
        cmd.write(twist(0.2))
        await until(lambda: board.commanded_velocity == (0.2, 0.0), 2.0)
        assert b.refused == 2


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_read_only_subscribes_to_nothing_and_writes_nothing() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        async with bridged(robot, read_only=True) as (_b, tg):
            g = Graph()
            odom = g.reader("rt/odom", m.Odometry)
            _kept = g.writer("rt/cmd_vel", m.Twist)
            await until(lambda: len(odom.read(N=1000)) > 5, 5.0)  # the bridge is up and seen
            assert g.readers_of["rt/cmd_vel"] == 0
            tg.cancel_scope.cancel()
        # The bridge ended: not even a zero was written (the device's own close does).
        assert len(sim.firmware.received) == 0


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.timing
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_odometry_tf_battery_and_diagnostics_from_a_chassis() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, namespace="robot1", diagnostics_period=0.2) as (_b, _),
    ):
        g = Graph()
        odom = g.reader("rt/robot1/odom", m.Odometry)
        tf = g.reader("rt/tf", m.TFMessage)
        battery = g.reader("rt/robot1/battery_state", m.BatteryState)
        diag = g.reader("rt/diagnostics", m.DiagnosticArray)
        got: dict[str, list[Any]] = {"odom": [], "tf": [], "battery": [], "diag": []}

        def collect() -> bool:
            for key, reader in (("odom", odom), ("tf", tf), ("battery", battery), ("diag", diag)):
                got[key] += [s for s in reader.take(N=1000) if hasattr(s, "__idl_typename__")]
            return len(got["odom"]) >= 50 and got["battery"] != [] and len(got["diag"]) >= 2

        started = time.monotonic()
        await until(collect, 10.0)
        rate = len(got["odom"]) / (time.monotonic() - started)
        assert rate > 25  # the chassis's 50 Hz, less discovery
        o = got["odom"][-1]
        assert (o.header.frame_id, o.child_frame_id) == ("robot1/odom", "robot1/base_link")
        assert abs(o.header.stamp.sec + o.header.stamp.nanosec * 1e-9 - time.time()) < 1.0
        assert all(o.pose.covariance[i * 7] > 0 for i in range(6))
        assert all(o.twist.covariance[i * 7] > 0 for i in range(6))
        t = got["tf"][-1].transforms[0]
        assert (t.header.frame_id, t.child_frame_id) == ("robot1/odom", "robot1/base_link")
        bat = got["battery"][-1]
        assert bat.voltage == pytest.approx(sim.firmware.battery_voltage, abs=0.1)
        assert math.isnan(bat.percentage)
        assert math.isnan(bat.current)
        status = got["diag"][-1].status[0]
        assert status.level == m.DIAGNOSTIC_OK, status
        assert status.hardware_id == sim.port
        assert status.name == "chassis_sdk: chassis"


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_a_reflex_shows_in_diagnostics() -> None:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, diagnostics_period=0.1) as (_b, _),
    ):
        diag = Graph().reader("rt/diagnostics", m.DiagnosticArray)
        await robot.set_velocity(0.2, 0.0, duration=3.0)
        sim.firmware.press_bumper(front=True)
        got: list[Any] = []

        def shown() -> bool:
            got.extend(s for s in diag.take(N=100) if hasattr(s, "__idl_typename__"))
            return any("last reflex" in {v.key for v in s.status[0].values} for s in got)

        await until(shown, 10.0)
    values = {v.key: v.value for s in got for v in s.status[0].values}
    assert values["reflexes"] == "bumper 1"
    assert values["last reflex"] == "reflex (front_bumper) -> stop"


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_battery_state_percentage_is_the_models_charge_once_known() -> None:
    from chassis_sdk import BatteryModel

    model = BatteryModel("lifepo4", cells=8, warmup=0.2, min_readings=1)
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, battery=model) as robot,
        bridged(robot, namespace="robot1") as (_b, _),
    ):
        battery = Graph().reader("rt/robot1/battery_state", m.BatteryState)
        got: list[Any] = []

        def known() -> bool:
            got.extend(s for s in battery.take(N=100) if hasattr(s, "__idl_typename__"))
            return any(not math.isnan(s.percentage) for s in got)

        await until(known, 10.0)
        charge = robot.battery_percentage
    latest = next(s for s in reversed(got) if not math.isnan(s.percentage))
    assert charge is not None
    assert 0.0 <= latest.percentage <= 1.0
    assert latest.percentage == pytest.approx(charge / 100, abs=0.05)
    assert latest.power_supply_technology == m.BATTERY_TECHNOLOGY["lifepo4"]


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_a_board_publishes_imu_and_a_latched_tf_static_for_late_joiners() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board, bridged(board) as (_b, _):
        g = Graph()
        imu = g.reader("rt/imu/data_raw", m.Imu)
        samples: list[Any] = []

        def collect() -> bool:
            samples.extend(s for s in imu.take(N=100) if hasattr(s, "__idl_typename__"))
            return len(samples) >= 3

        await until(collect, 10.0)
        s = samples[-1]
        assert s.header.frame_id == "imu_link"
        assert s.orientation_covariance[0] == -1.0
        assert math.sqrt(sum(v**2 for v in (s.linear_acceleration.x, s.linear_acceleration.y,
                                             s.linear_acceleration.z))) > 1.0  # fmt: skip
        # A reader that joins long after the bridge still gets /tf_static.
        late = g.reader("rt/tf_static", m.TFMessage, transient=True, depth=1)
        static: list[Any] = []

        def latched() -> bool:
            static.extend(s for s in late.take(N=10) if hasattr(s, "__idl_typename__"))
            return bool(static)

        await until(latched, 5.0)
        (transform,) = static[-1].transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ("base_link", "imu_link")


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_the_bridge_ending_stops_the_robot_and_leaves_the_graph() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        g = Graph()
        left = asyncio.Event()
        loop = asyncio.get_running_loop()

        counts: list[int] = []

        def on_match(_r: Any, status: Any) -> None:
            counts.append(int(status.current_count))
            if status.current_count == 0 and status.total_count > 0:
                loop.call_soon_threadsafe(left.set)

        kept = DataReader(  # kept: deleting it would stop its listener
            g.dp,
            g.topic("rt/odom", m.Odometry),
            Qos(Policy.Reliability.Reliable(0)),
            Listener(on_subscription_matched=on_match),  # type: ignore[no-untyped-call]
        )
        async with bridged(robot, command_timeout=5.0) as (_b, tg):
            w = g.writer("rt/cmd_vel", m.Twist)
            await matched(g, "rt/cmd_vel")
            w.write(twist(0.2))
            await until(lambda: any(c.linear_mm == 200 for _, c in drives(sim)), 2.0)
            tg.cancel_scope.cancel()
        # The bridge's last word is a zero (on its way through the pty when it ends).
        await until(lambda: drives(sim)[-1][1] == DriveVelocity(0, 0.0), 2.0)
        async with asyncio.timeout(2.0):
            await left.wait()
        assert counts[-1] == 0
        # The readers' wake threads (out of Cyclone's wait sets) went with the bridge.
        assert not [t.name for t in threading.enumerate() if t.name.startswith("dds ")]
        assert kept is not None


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_a_static_peer_that_does_not_resolve_is_left_out_not_fatal() -> None:
    # Cyclone aborts the process on a peer it cannot resolve: the bridge resolves them
    # first (in a thread) and leaves such a one out, with a warning.
    discovery = Discovery(domain_id=DOMAIN, static_peers=("robot2.invalid", "localhost"))
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        bridged(robot, discovery=discovery) as (b, _),
    ):
        assert b.discovery.static_peers == ("127.0.0.1",)
        g = Graph()
        w = g.writer("rt/cmd_vel", m.Twist)
        await matched(g, "rt/cmd_vel")
        w.write(twist(0.1))
        await until(lambda: any(c.linear_mm == 100 for _, c in drives(sim)), 2.0)


@pytest.mark.parametrize(
    "peers",
    [
        pytest.param("10.0.0.2", id="a-string"),
        pytest.param(("::1",), id="ipv6"),
        pytest.param(("0",), id="zero"),
        pytest.param(("0.0.0.0",), id="unspecified"),
        pytest.param(("239.255.0.1",), id="multicast"),
        pytest.param(("a..b",), id="empty-label"),
        pytest.param((3,), id="not-a-str"),
    ],
)
def test_static_peers_cyclone_would_crash_on_are_refused(peers: Any) -> None:
    with pytest.raises((TypeError, ValueError)):
        Discovery(static_peers=peers)


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_two_bridges_in_one_process_share_a_domain_and_a_different_one_is_refused() -> None:
    localhost = Discovery(domain_id=DOMAIN, range="LOCALHOST")
    async with (
        ChassisSimulator() as sim1,
        ChassisSimulator() as sim2,
        Chassis(sim1.port) as robot1,
        Chassis(sim2.port) as robot2,
        bridged(robot1, namespace="r1", discovery=localhost) as (_b1, _),
        bridged(robot2, namespace="r2", discovery=localhost) as (_b2, _),
    ):
        g = Graph()
        w1 = g.writer("rt/r1/cmd_vel", m.Twist)
        w2 = g.writer("rt/r2/cmd_vel", m.Twist)
        await matched(g, "rt/r1/cmd_vel")
        await matched(g, "rt/r2/cmd_vel")
        w1.write(twist(0.1))
        w2.write(twist(0.2))
        await until(lambda: any(c.linear_mm == 100 for _, c in drives(sim1)), 2.0)
        await until(lambda: any(c.linear_mm == 200 for _, c in drives(sim2)), 2.0)
        other = Discovery(domain_id=DOMAIN, static_peers=("127.0.0.1",))
        with pytest.raises(ValueError, match="configured otherwise"):
            Participant(other, "r3")  # what the third bridge's run() would make first


@pytest.mark.parametrize(
    ("statuses", "told"),
    [
        # (count, from matching?) as Cyclone reports them, and "no writer left" told
        pytest.param([(1, True), (1, False), (0, False), (0, True)], 1, id="both-fall-once"),
        pytest.param([(1, True), (1, False), (0, True), (0, False)], 1, id="matching-first"),
        pytest.param([(1, True), (0, True)], 1, id="liveliness-never-came"),
        pytest.param([(2, True), (2, False), (1, True), (1, False)], 0, id="one-of-two-left"),
        pytest.param(
            [(1, True), (1, False), (0, False), (0, True), (1, True), (1, False), (0, False)],
            2,
            id="gone-back-gone",
        ),
    ],
)
async def test_no_writer_left_is_told_once_per_leaving(
    statuses: list[tuple[int, bool]], told: int
) -> None:
    from chassis_sdk.integrations.ros2.dds import Reader

    reader: Reader[Any] = Reader("/cmd_vel", asyncio.get_running_loop())
    calls: list[int] = []
    reader.on_no_writers = lambda: calls.append(1)
    for count, matched in statuses:
        reader._on_loop(count, matched)  # what the listener schedules on the loop
    assert len(calls) == told


# --- by callback: no task per stream, readings in order, the newest kept ---------------------


def samples(reader: DataReader[Any]) -> list[Any]:
    """What ``reader`` holds now, taken (the samples only, not the instance states)."""
    return [s for s in reader.take(N=1000) if hasattr(s, "__idl_typename__")]


def seconds(stamp: Any) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


@asynccontextmanager
async def device_on_simulator(board: bool) -> AsyncIterator[tuple[Any, Any]]:
    simulator = BoardSimulator() if board else ChassisSimulator()
    device = Board if board else Chassis
    async with simulator as sim, device(sim.port) as robot:
        yield sim, robot


@contextmanager
def raw_pty() -> Iterator[tuple[int, str]]:
    """A pty in raw mode: its master (what the device writes) and the port's name."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
@pytest.mark.parametrize("board", [False, True], ids=["chassis", "board"])
async def test_the_ros2_bridge_has_no_task_per_stream_and_odometry_comes_in_order(
    board: bool,
) -> None:
    # The bridge takes its data by callback (issue 29, item 3): a fixed number of tasks
    # whatever the device's streams (a chassis has three, a board four).
    async with device_on_simulator(board) as (_sim, robot), bridged(robot) as (bridge, _):
        odom = Graph().reader("rt/odom", m.Odometry)
        got: list[Any] = []

        def enough() -> bool:
            got.extend(samples(odom))
            return len(got) >= 40

        await until(enough, 10.0)
        # run() itself, and one task each for the readings, /diagnostics, cmd_vel and
        # emergency_stop: before, one per stream instead of "_publish" (a chassis's
        # odometry and telemetry, a board's odometry, imu and battery).
        assert tasks_of("ros2/bridge.py") == ["_diagnostics", "_publish", "run"]
        assert tasks_of("ros2/commands.py") == ["commands_from", "estops_from"]
        published = bridge.odometry_published
    stamps = [seconds(o.header.stamp) for o in got]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) == len(stamps)
    assert published >= len(got)
    assert bridge.dropped_readings == 0


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_a_link_lost_for_good_ends_the_bridge_with_connection_lost() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:  # no reconnect
        bridge = Ros2Bridge(robot, discovery=Discovery(domain_id=DOMAIN))
        ended: list[BaseException] = []

        async def run() -> None:
            try:
                await bridge.run()
            except* ConnectionLostError as group:
                ended.extend(group.exceptions)

        async with anyio.create_task_group() as tg:
            tg.start_soon(run)
            await bridge.started.wait()
            await until(lambda: bridge.odometry_published > 5, 5.0)
            sim.unplug()
            with anyio.fail_after(5.0):
                while not ended:
                    await asyncio.sleep(0.01)
        assert ended  # (before: one for each stream's task)
        assert all(sim.port in str(error) for error in ended)


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_a_burst_keeps_the_newest_queue_size_readings_and_counts_the_rest() -> None:
    encoder = BoardEncoder()
    zero = Vector3(0.0, 0.0, 0.0)
    # Accelerations of k / 164 g (exact on the wire: 164 counts a g).
    burst = b"".join(
        encoder.encode(ImuSample(accel=Vector3(k / 164, 0.0, 0.0), gyro=zero, mag=zero))
        for k in range(1, 21)
    )
    with raw_pty() as (master, path):
        async with (
            Board(path, queue_size=4) as board,
            bridged(board, read_only=True) as (bridge, _),
        ):
            imu = Graph().reader("rt/imu/data_raw", m.Imu)
            probe = encoder.encode(ImuSample(accel=Vector3(1.0, 0.0, 0.0), gyro=zero, mag=zero))
            seen: list[Any] = []

            def matched() -> bool:  # the reader sees the bridge's writer
                os.write(master, probe)
                seen.extend(samples(imu))
                return bool(seen)

            await until(matched, 10.0)
            dropped = bridge.dropped_readings
            os.write(master, burst)  # one read, 20 readings before the publisher runs
            got: list[Any] = []

            def arrived() -> bool:
                got.extend(samples(imu))
                return any(round(s.linear_acceleration.x / 9.80665 * 164) == 20 for s in got)

            start = time.monotonic()
            await until(arrived, 5.0)
            assert time.monotonic() - start < 5.0
    ks = [round(s.linear_acceleration.x / 9.80665 * 164) for s in got]
    ks = [k for k in ks if k != 164]  # the probes still in flight
    assert ks == [17, 18, 19, 20]  # the newest queue_size, in order
    # The 16 older ones of the burst (and any probe read with it) dropped and counted.
    assert bridge.dropped_readings - dropped >= 16
