"""Odometry: the integrator on its own (exact arcs, any sampling, gaps), then against
the simulators' true pose."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chassis_sdk import Board, Chassis
from chassis_sdk.core.odometry import OdometryIntegrator, wrap_angle
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

ROOT = Path(__file__).resolve().parent.parent


def _example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def run(samples: list[tuple[float, float, float]]) -> OdometryIntegrator:
    odo = OdometryIntegrator(max_gap=10.0)
    for v, w, t in samples:
        odo.update(v, w, t)
    return odo


# --- the integrator ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "times",
    [
        pytest.param([i * 0.02 for i in range(101)], id="regular 50 Hz"),
        pytest.param([0, 0.003, 0.05, 0.051, 0.3, 0.9, 1.2, 2.0], id="irregular"),
        pytest.param([i * 0.02 for i in range(101) if i % 7], id="dropped frames"),
    ],
)
def test_straight_line_is_exact_however_it_is_sampled(times: list[float]) -> None:
    odo = run([(0.5, 0.0, t) for t in times])
    assert odo.x == pytest.approx(0.5 * (times[-1] - times[0]), abs=1e-12)
    assert odo.y == 0.0


def test_a_full_circle_closes_and_a_quarter_lands_on_the_arc() -> None:
    v, w = 0.5, 0.8  # radius 0.625 m
    period = 2 * math.pi / w
    odo = run([(v, w, period * i / 37) for i in range(38)])  # an odd, coarse sampling
    assert math.hypot(odo.x, odo.y) < 1e-9
    assert odo.heading == pytest.approx(2 * math.pi)
    quarter = run([(v, w, 0.0), (v, w, period / 4)])
    assert (quarter.x, quarter.y) == pytest.approx((0.625, 0.625))


@settings(max_examples=200, deadline=None)
@given(
    segments=st.lists(
        st.tuples(st.floats(-1, 1), st.floats(-2, 2), st.floats(0.01, 0.4)),
        min_size=1,
        max_size=8,
    ),
    splits=st.lists(st.integers(1, 6), min_size=8, max_size=8),
)
def test_subdividing_samples_does_not_change_the_pose(
    segments: list[tuple[float, float, float]], splits: list[int]
) -> None:
    """Piecewise-constant motion: one sample per segment or several give the same pose."""
    coarse, fine, t = [(0.0, 0.0, 0.0)], [(0.0, 0.0, 0.0)], 0.0
    for (v, w, dt), k in zip(segments, splits, strict=False):
        fine += [(v, w, t + dt * (i + 1) / k) for i in range(k)]
        t += dt
        coarse.append((v, w, t))
    a, b = run(coarse), run(fine)
    assert (a.x, a.y, a.heading) == pytest.approx((b.x, b.y, b.heading), abs=1e-9)


# A ramp at 50 Hz (0.1, 0.2, 0.3, 0.4 m/s at 20 ms), and the same frames read in one burst
# after the loop was held up: the frames after the first share its read time. Each row:
# the receive times of the four samples after one at t=0 -> x (m).
BURST_ROWS = [
    ("regular", [0.02, 0.04, 0.06, 0.08], 0.02 * (0.1 + 0.2 + 0.3 + 0.4)),
    ("three in one read", [0.02, 0.08, 0.08, 0.08], 0.02 * 0.1 + 0.02 * (0.2 + 0.3 + 0.4)),
    ("all four in one read", [0.08, 0.08, 0.08, 0.08], 0.02 * (0.1 + 0.2 + 0.3 + 0.4)),
    ("two bursts", [0.04, 0.04, 0.08, 0.08], 0.02 * (0.1 + 0.2 + 0.3 + 0.4)),
    ("after a gap", [0.02, 0.9, 0.9, 0.9], 0.02 * 0.1),  # the gap: nothing to share
]


@pytest.mark.parametrize("deferred", [False, True], ids=["update", "defer"])
@pytest.mark.parametrize(
    ("times", "x"), [r[1:] for r in BURST_ROWS], ids=[r[0] for r in BURST_ROWS]
)
def test_samples_of_one_read_share_its_interval(
    times: list[float], x: float, deferred: bool
) -> None:
    # Before: the first sample of a burst stood for the whole interval (0.4 m/s for
    # 60 ms where the robot went 0.2, 0.3, 0.4), and the rest for nothing.
    odo = OdometryIntegrator(max_gap=0.5)
    odo.update(0.0, 0.0, 0.0)
    for v, t in zip((0.1, 0.2, 0.3, 0.4), times, strict=True):
        (odo.defer if deferred else odo.update)(v, 0.1, t)
    assert odo.x == pytest.approx(x, abs=1e-4)  # the small turn: 0.1 rad/s
    assert odo.heading == pytest.approx(0.1 * (times[-1] if times[1] < 0.5 else 0.02))


def test_a_long_gap_is_not_integrated() -> None:
    odo = OdometryIntegrator(max_gap=0.5)
    odo.update(1.0, 0.0, 0.0)
    odo.update(1.0, 0.0, 0.1)
    pose = odo.update(1.0, 0.0, 3.0)  # an outage: the speed across it is unknown
    assert pose.x == pytest.approx(0.1)
    assert odo.skipped_gaps == 1
    assert odo.update(1.0, 0.0, 3.1).x == pytest.approx(0.2)


def test_reset_heading_wrap_and_bad_options() -> None:
    odo = OdometryIntegrator()
    odo.reset(1.0, 2.0, 3 * math.pi)
    pose = odo.update(0.0, 0.0, 5.0)
    assert (pose.x, pose.y) == (1.0, 2.0)
    assert pose.heading == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == math.pi
    with pytest.raises(ValueError, match="max_gap"):
        OdometryIntegrator(max_gap=0)


def test_an_external_heading_replaces_the_integrated_one() -> None:
    odo = OdometryIntegrator()
    odo.update(1.0, 0.0, 0.0, heading=0.0)
    pose = odo.update(1.0, 0.0, 0.5, heading=math.pi)  # turned half round per the gyro
    assert pose.heading == pytest.approx(math.pi)
    assert (pose.x, pose.y) == pytest.approx((0.0, 1 / math.pi))  # a half circle of 0.5 m


_SAMPLES = st.lists(
    st.tuples(
        st.floats(-2, 2),  # linear (m/s)
        st.floats(-4, 4),  # angular (rad/s)
        st.floats(0, 0.8),  # time since the previous sample: some past max_gap, some 0
        st.one_of(st.none(), st.floats(-10, 10)),  # an external heading, or none
        st.sampled_from(["defer", "advance", "read", "reset", "max_gap"]),
    ),
    max_size=200,
)


@given(_SAMPLES)
@settings(max_examples=150, deadline=None)
def test_deferred_samples_give_the_same_pose_to_the_bit(steps: list[tuple[Any, ...]]) -> None:
    """A device defers the samples nobody listens to and integrates them when the pose
    is read or changed (or 64 wait): the same pose, gaps and last sample to the bit as
    integrating each at once, whatever reads, resets and max_gap changes come between."""
    now_, later = OdometryIntegrator(), OdometryIntegrator()
    t = 100.0
    for linear, angular, dt, heading, what in steps:
        t += dt
        if what == "reset":
            now_.reset(linear, angular, t)
            later.reset(linear, angular, t)
        elif what == "max_gap":
            now_.max_gap = later.max_gap = 0.05 + dt
        elif what == "read":
            assert (later.x, later.y, later.heading) == (now_.x, now_.y, now_.heading)
            assert later.current() == now_.current()
        else:
            now_.advance(linear, angular, t, heading)
            (later.defer if what == "defer" else later.advance)(linear, angular, t, heading)
    assert later.current() == now_.current()
    assert (later.x, later.y, later.heading) == (now_.x, now_.y, now_.heading)
    assert later.skipped_gaps == now_.skipped_gaps


def test_deferred_samples_wait_at_most_the_limit() -> None:
    from chassis_sdk.core.odometry import DEFER_LIMIT

    odo = OdometryIntegrator()
    for i in range(DEFER_LIMIT - 1):
        odo.defer(1.0, 0.0, i * 0.01)
    assert len(odo._deferred) == DEFER_LIMIT - 1  # nothing integrated yet
    odo.defer(1.0, 0.0, (DEFER_LIMIT - 1) * 0.01)
    assert not odo._deferred  # the limit integrated them all
    assert odo.x == pytest.approx((DEFER_LIMIT - 1) * 0.01)


def test_a_device_defers_unheard_samples_within_the_limit_and_to_the_bit() -> None:
    """``Reports.integrate`` with nobody listening defers each calibrated sample: never
    `DEFER_LIMIT` of them wait, and the pose read is the one integrating each at once
    gives, to the bit; with a listener, each is integrated and published at once."""
    import logging

    from chassis_sdk.core.calibration import Calibration
    from chassis_sdk.core.dispatch import Broadcast
    from chassis_sdk.core.observation import Reports
    from chassis_sdk.core.odometry import DEFER_LIMIT, Odometry

    reports = Reports("test", logging.getLogger("test"), Broadcast(8), Broadcast(8), None)
    reports.calibration = Calibration(linear_scale=1.02, angular_scale=0.97)
    reference = OdometryIntegrator()
    samples = [(0.3 + i * 1e-3, 0.2 - i * 2e-3, 10.0 + i * 0.02) for i in range(5 * DEFER_LIMIT)]
    for i, (v, w, t) in enumerate(samples):
        reports.integrate(v, w, t)
        reference.advance(v * 1.02, w * 0.97, t)
        assert len(reports.pose._deferred) == (i + 1) % DEFER_LIMIT
    assert reports.latest_odometry == reference.current()
    assert not reports.pose._deferred
    heard: list[Odometry] = []
    listener = reports.odometry.listen(heard.append)  # (held: a dropped one stops)
    reports.integrate(0.5, 0.1, 20.0)
    reference.advance(0.5 * 1.02, 0.1 * 0.97, 20.0)
    assert not reports.pose._deferred
    assert heard == [reference.current()]
    listener.close()


# --- against the simulators -------------------------------------------------------------------


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.timeout(90)
async def test_a_1_m_square_closes_and_odometry_matches_the_simulators_truth() -> None:
    """Stated tolerance: the square closes within 2 cm and 1 degree by odometry, and
    odometry is within 1 cm and 0.5 degree of the simulator's true pose at the end."""
    drive = _example("drive_to_pose")
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        end = await drive.square(robot, 1.0)
        x, y, heading = sim.firmware.pose
    assert math.hypot(end.x, end.y) < 0.02
    assert abs(math.degrees(end.heading)) < 1.0
    assert math.hypot(end.x - x, end.y - y) < 0.01
    assert abs(math.degrees(wrap_angle(end.heading - heading))) < 0.5
    assert robot.stats.sequence_gaps == 0


@pytest.mark.integration
async def test_chassis_wheel_odometry_with_track_from_0x89() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.configure_odometry("wheels")  # reads track_width from the chassis
        robot.reset_odometry()
        await robot.set_velocity(0.4, 0.8, duration=1.0)
        async for pose in robot.odometry():
            if pose.timestamp > 0 and robot.commanded_velocity is None and pose.linear == 0:
                break
        x, y, heading = sim.firmware.pose
        assert pose.distance_to(x, y) < 0.01
        assert pose.heading == pytest.approx(wrap_angle(heading), abs=0.01)
        with pytest.raises(ValueError, match="slip_factor"):
            await robot.configure_odometry("wheels", track_width=0.5, slip_factor=0.5)
        with pytest.raises(ValueError, match="source"):
            await robot.configure_odometry("gps")


@pytest.mark.integration
async def test_board_odometry_with_imu_heading_matches_the_simulator() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board:
        await board.configure_odometry(heading="imu")
        await anext(board.odometry())
        board.reset_odometry()
        start = sim.firmware.pose
        await board.set_velocity(0.3, 0.6, duration=1.5)
        async for pose in board.odometry():
            if board.commanded_velocity is None and abs(pose.linear) < 1e-3:
                break
        x, y, heading = (a - b for a, b in zip(sim.firmware.pose, start, strict=True))
        assert pose.distance_to(x, y) < 0.03
        assert pose.heading == pytest.approx(wrap_angle(heading), abs=math.radians(2))


def test_the_latest_pose_is_right_whether_or_not_anyone_listens() -> None:
    """The pose is built per frame only for a listener; read later it is the same."""
    from chassis_sdk import Chassis
    from chassis_sdk.core.notifier import Notifier
    from chassis_sdk.devices.chassis.firmware import ChassisFirmware
    from chassis_sdk.devices.chassis.protocol import ChassisEncoder

    firmware, encoder = ChassisFirmware(), ChassisEncoder()
    firmware.on_connect(0.0)
    firmware.receive(encoder.drive_velocity(0.4, 0.6), 0.0)
    frames = [(i * 0.01, firmware.poll(i * 0.01)) for i in range(1, 200)]
    listened, alone = Chassis("/dev/a"), Chassis("/dev/b")
    poses: list[object] = []
    keep = Notifier(listened)
    keep.listen("odometry", poses.append)
    assert alone.latest_odometry is None
    for i, (now, data) in enumerate(frames):
        listened.feed(data, now)
        alone.feed(data, now)
        if i == 100:
            assert alone.latest_odometry is not None
            assert alone.latest_odometry == listened.latest_odometry  # read mid-way
    assert alone._reports.odometry.latest is None  # nothing was built since
    assert alone.latest_odometry == listened.latest_odometry == poses[-1]
    assert listened.latest_odometry is not None
    assert listened.latest_odometry.x > 0.1
    alone.reset_odometry()
    assert alone.latest_odometry == poses[-1]  # the last pose before the reset
    keep.close()
