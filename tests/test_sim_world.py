"""The simulators' world: the geometry (contact, sweep, the command-line form) as tables,
the firmware models in a world sans-IO with an injected clock (bumpers, stopped wheels,
the IMU's impact, the true pose apart from odometry, repeatable slip), and one
integration test of an unmodified `Chassis` running into a wall."""

from __future__ import annotations

import math
from collections.abc import Iterator

import anyio
import pytest

from chassis_sdk.protocol import (
    BoardDecoder,
    BoardEncoder,
    ChassisDecoder,
    ChassisEncoder,
    ChassisStatus,
    DriveVelocity,
    FaultClear,
    ImuSample,
    Telemetry,
    VelocityCommand,
    VelocityFeedback,
)
from chassis_sdk.sim import (
    BoardFirmware,
    BoardSpec,
    ChassisFirmware,
    ChassisSimulator,
    ChassisSpec,
    Wall,
    World,
)
from chassis_sdk.sim.world import SWEEP_STEP

ARENA = World.arena(2, 2)  # walls at x = ±1 and y = ±1
BOX = (0.6, 0.4)  # length along the heading, width


# --- geometry ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pose", "touches"),
    [
        pytest.param((0.0, 0.0, 0.0), False, id="centre"),
        pytest.param((0.69, 0.0, 0.0), False, id="a-centimetre-short-of-the-wall"),
        pytest.param((0.7001, 0.0, 0.0), True, id="front-edge-on-the-wall"),
        pytest.param((-0.71, 0.0, 0.0), True, id="rear-edge-past-the-wall"),
        pytest.param((0.0, 0.79, 0.0), False, id="side-short-of-the-wall"),
        pytest.param((0.0, 0.81, 0.0), True, id="side-past-the-wall"),
        pytest.param((0.0, 0.69, math.pi / 2), False, id="turned-front-short"),
        pytest.param((0.0, 0.71, math.pi / 2), True, id="turned-front-past"),
        pytest.param((0.6, 0.0, math.pi / 4), False, id="diagonal-corner-short"),
        pytest.param((0.7, 0.0, math.pi / 4), True, id="diagonal-corner-past"),
        pytest.param((3.0, 0.0, 0.0), False, id="outside-between-no-walls"),
    ],
)
def test_a_box_touches_the_arena_walls_where_geometry_says(
    pose: tuple[float, float, float], touches: bool
) -> None:
    assert ARENA.collides(pose, *BOX) is touches


@pytest.mark.parametrize(
    ("pose", "front"),
    [
        pytest.param((0.75, 0.0, 0.0), True, id="forward-into-+x"),
        pytest.param((-0.75, 0.0, 0.0), False, id="backward-into--x"),
        pytest.param((-0.75, 0.0, math.pi), True, id="turned-round-into--x"),
        pytest.param((0.0, 0.75, -math.pi / 2), False, id="facing-down-backed-into-+y"),
    ],
)
def test_the_contact_is_in_the_box_frame(pose: tuple[float, float, float], front: bool) -> None:
    touch = ARENA.contact(pose, *BOX)
    assert touch is not None
    assert (touch[0] > 0) is front
    assert abs(touch[0]) == pytest.approx(0.3, abs=0.06)


@pytest.mark.parametrize(
    ("start", "end", "stop", "front"),
    [
        pytest.param((0, 0, 0), (2, 0, 0), (0.7, 0, 0), True, id="forward-stops-at-the-wall"),
        pytest.param((0, 0, 0), (-2, 0, 0), (-0.7, 0, 0), False, id="backward-stops"),
        pytest.param((0, 0, 0), (0.5, 0, 0), (0.5, 0, 0), None, id="free-move"),
        pytest.param((0.7 - 1e-6, 0, 0), (0, 0, 0), (0, 0, 0), None, id="away-from-the-wall"),
        pytest.param((0, 0, 0), (2, 2, 0), (0.7, 0.7, 0), True, id="diagonal"),
    ],
)
def test_a_sweep_stops_touching_the_wall_never_inside(
    start: tuple[float, float, float],
    end: tuple[float, float, float],
    stop: tuple[float, float, float],
    front: bool | None,
) -> None:
    pose, touch = ARENA.sweep(start, end, *BOX)
    assert pose == pytest.approx(stop, abs=1e-4)
    assert not ARENA.collides(pose, *BOX)
    if front is None:
        assert touch is None
        assert pose == end
    else:
        assert touch is not None
        assert (touch[0] > 0) is front


def test_a_long_step_does_not_pass_through_a_thin_wall() -> None:
    wall = World((Wall(1.0, -1.0, 1.0, 1.0),))
    pose, touch = wall.sweep((0, 0, 0), (5.0, 0, 0), 0.1, 0.1)  # 5 m in one step
    assert touch is not None
    assert pose[0] == pytest.approx(0.95, abs=1e-4)
    assert SWEEP_STEP < 0.1  # what keeps a box from skipping over a wall


def test_turning_on_the_spot_against_a_wall_is_stopped() -> None:
    pose, touch = ARENA.sweep((0.69, 0, 0), (0.69, 0, math.pi / 2), *BOX)
    assert touch is not None
    assert 0 < pose[2] < math.pi / 2
    assert not ARENA.collides(pose, *BOX)


def test_a_world_without_walls_is_open_space() -> None:
    assert World().sweep((0, 0, 0), (9, 9, 1), *BOX) == ((9, 9, 1), None)


@pytest.mark.parametrize(
    ("spec", "walls"),
    [
        pytest.param("arena:4x3", World.arena(4, 3).walls, id="arena"),
        pytest.param("arena:4X3", World.arena(4, 3).walls, id="arena-capital-x"),
        pytest.param("wall:1,-1,1,1", (Wall(1, -1, 1, 1),), id="wall"),
        pytest.param(
            "arena:4x3+wall:1,-1.5,1,0",
            (*World.arena(4, 3).walls, Wall(1, -1.5, 1, 0)),
            id="arena-and-wall",
        ),
    ],
)
def test_world_parse(spec: str, walls: tuple[Wall, ...]) -> None:
    assert World.parse(spec).walls == walls


@pytest.mark.parametrize(
    ("spec", "why"),
    [
        pytest.param("arena:4", "no 'x' between width and height", id="one-side"),
        pytest.param("arena:0x3", "width must be", id="zero-side"),
        pytest.param("arena:-4x3", "width must be", id="negative-side"),
        pytest.param("arena:nanx3", "width must be", id="nan"),
        pytest.param("arena:axb", "could not convert", id="not-numbers"),
        pytest.param("wall:1,2,3", "3 numbers, not 4", id="three-numbers"),
        pytest.param("room:4x3", "unknown kind 'room'", id="unknown-kind"),
        pytest.param("", "unknown kind ''", id="empty"),
        pytest.param("arena:4x3+", "unknown kind ''", id="trailing-plus"),
    ],
)
def test_world_parse_refuses_with_what_is_expected(spec: str, why: str) -> None:
    with pytest.raises(ValueError, match="expected arena:WxH") as info:
        World.parse(spec)
    assert why in str(info.value)
    assert "\n" not in str(info.value)


# --- the chassis firmware in a world (sans-IO, injected clock) ---------------------------


class ChassisRun:
    """A chassis firmware model driven by a host at 50 Hz on a made-up clock."""

    def __init__(self, firmware: ChassisFirmware) -> None:
        self.fw = firmware
        self.now = 100.0
        self.encoder = ChassisEncoder()
        self.decoder = ChassisDecoder()
        self.telemetry: list[Telemetry] = []
        firmware.on_connect(self.now)

    def send(self, message: DriveVelocity | FaultClear) -> None:
        if isinstance(message, FaultClear):
            data = self.encoder.clear_faults(message)
        else:
            data = self.encoder.encode(message)
        self.fw.receive(data, self.now)

    def drive(self, linear: float, seconds: float, angular: float = 0.0) -> Iterator[Telemetry]:
        """Command ``linear`` every step for ``seconds``; each telemetry frame sent."""
        for _ in range(round(seconds / 0.02)):
            self.now += 0.02
            self.send(DriveVelocity(round(linear * 1000), angular))
            for message in self.decoder.feed(self.fw.poll(self.now)):
                if isinstance(message, Telemetry):
                    self.telemetry.append(message)
                    yield message


def test_driving_into_a_wall_latches_the_front_bumper_and_stops_the_wheels() -> None:
    run = ChassisRun(ChassisFirmware(world=ARENA))
    length = run.fw.footprint[0]
    frames = list(run.drive(0.5, 3.0))
    hit = next(i for i, t in enumerate(frames) if ChassisStatus.FRONT_BUMPER in t.status)
    assert frames[hit - 1].wheels.front_left == pytest.approx(0.5)  # at speed until then
    for t in frames[hit:]:  # commanded 0.5 m/s all along, measured 0
        assert t.wheels == (0.0, 0.0, 0.0, 0.0)
        assert t.linear == 0.0
    assert ChassisStatus.REAR_BUMPER not in frames[-1].status
    x, y, heading = run.fw.true_pose
    assert x == pytest.approx(1.0 - length / 2, abs=1e-4)  # touching, not inside
    assert (y, heading) == (0.0, 0.0)
    assert run.fw.impacts == 1


def test_reversing_into_a_wall_latches_the_rear_bumper() -> None:
    run = ChassisRun(ChassisFirmware(world=ARENA))
    frames = list(run.drive(-0.5, 3.0))
    assert ChassisStatus.REAR_BUMPER in frames[-1].status
    assert ChassisStatus.FRONT_BUMPER not in frames[-1].status
    assert run.fw.true_pose[0] == pytest.approx(-(1.0 - run.fw.footprint[0] / 2), abs=1e-4)


def test_after_clear_faults_it_backs_away_but_cannot_push_on() -> None:
    run = ChassisRun(ChassisFirmware(world=ARENA))
    list(run.drive(0.5, 3.0))
    at_wall = run.fw.true_pose
    run.send(FaultClear.FRONT_BUMPER)
    frames = list(run.drive(0.5, 0.2))  # forward again: hits at once
    assert ChassisStatus.FRONT_BUMPER in frames[-1].status
    assert run.fw.true_pose[0] == pytest.approx(at_wall[0], abs=1e-6)
    assert run.fw.impacts == 2
    run.send(FaultClear.FRONT_BUMPER)
    frames = list(run.drive(-0.3, 1.0))  # backward: free
    assert not frames[-1].status & (ChassisStatus.FRONT_BUMPER | ChassisStatus.REAR_BUMPER)
    assert frames[-1].wheels.front_left == pytest.approx(-0.3)
    assert run.fw.true_pose[0] < at_wall[0] - 0.1


def test_a_world_the_robot_does_not_fit_in_is_refused() -> None:
    with pytest.raises(ValueError, match=r"the chassis \(0.67 x 0.725 m\) at \(0, 0\) touches"):
        ChassisFirmware(world=World.arena(0.6, 3))
    with pytest.raises(ValueError, match="touches a wall of this world"):
        BoardFirmware(world=World.arena(0.2, 3))
    with pytest.raises(ValueError, match="touches a wall"):
        ChassisSimulator(world=World.parse("wall:0,-1,0,1"))


def test_the_footprint_is_the_spec_s_or_the_chassis_size() -> None:
    assert ChassisFirmware().footprint == pytest.approx((0.5 + 0.17, 0.725))
    assert ChassisFirmware(ChassisSpec(footprint=(0.4, 0.3))).footprint == (0.4, 0.3)
    with pytest.raises(ValueError, match="footprint width"):
        ChassisSpec(footprint=(0.4, 0.0))


def _odometry(frames: list[Telemetry], period: float = 0.02) -> float:
    return sum(t.linear * period for t in frames)


def test_the_true_pose_is_apart_from_what_the_encoders_report() -> None:
    spec = ChassisSpec(wheel_diameter_error=0.02)
    run = ChassisRun(ChassisFirmware(spec))
    frames = list(run.drive(0.4, 2.0))
    reported = _odometry(frames)
    assert run.fw.true_pose[0] == pytest.approx(1.02 * reported, rel=0.02)
    assert run.fw.true_pose == run.fw.pose


def _slipping_run(seed: int) -> tuple[float, float, float]:
    run = ChassisRun(ChassisFirmware(ChassisSpec(slip_noise=0.05, seed=seed)))
    list(run.drive(0.4, 1.0, angular=0.5))
    return run.fw.true_pose


def test_slip_is_random_but_repeatable_given_a_seed() -> None:
    run = ChassisRun(ChassisFirmware())
    list(run.drive(0.4, 1.0, angular=0.5))
    exact = run.fw.true_pose
    assert _slipping_run(1) == _slipping_run(1)
    assert _slipping_run(1) != _slipping_run(2)
    assert _slipping_run(1) != exact
    assert _slipping_run(1) == pytest.approx(exact, rel=0.05, abs=0.01)  # small, as asked


def test_no_world_is_open_space_as_before() -> None:
    run = ChassisRun(ChassisFirmware())
    assert run.fw.world is None
    frames = list(run.drive(1.0, 3.0))
    assert not frames[-1].status & ChassisStatus.FRONT_BUMPER
    assert run.fw.true_pose[0] > 2.0


def test_a_world_can_be_given_and_taken_away_while_it_runs() -> None:
    run = ChassisRun(ChassisFirmware())
    run.fw.world = ARENA
    list(run.drive(0.5, 3.0))
    assert run.fw.impacts == 1
    run.fw.world = None
    run.send(FaultClear.FRONT_BUMPER)
    list(run.drive(0.5, 1.0))
    assert run.fw.true_pose[0] > 1.0


# --- the board firmware in a world ----------------------------------------------------------


def test_a_board_running_into_a_wall_shows_the_impact_on_its_imu() -> None:
    fw = BoardFirmware(BoardSpec(accel_noise=0.0, gyro_noise=0.0), world=ARENA)
    encoder, decoder = BoardEncoder(), BoardDecoder()
    now = 50.0
    fw.on_connect(now)
    accel_x: list[float] = []
    feedback: list[float] = []
    for _ in range(400):  # 4 s at 100 Hz, commanding 0.5 m/s all along
        now += 0.01
        fw.receive(encoder.encode(VelocityCommand(500, 0)), now)
        for message in decoder.feed(fw.poll(now)):
            if isinstance(message, ImuSample):
                accel_x.append(message.accel.x)
            elif isinstance(message, VelocityFeedback):
                feedback.append(message.linear)
    assert fw.impacts == 1
    assert fw.true_pose[0] == pytest.approx(1.0 - fw.spec.footprint[0] / 2, abs=1e-4)
    spike = min(accel_x)
    assert spike < -4.0  # 0.5 m/s to 0 within one 10 ms IMU period: about -5 g
    assert sorted(accel_x)[1] > -0.2  # one sample shows it; pushing on is no new impact
    assert feedback[-1] == 0.0  # commanded, not moving
    assert max(feedback) == pytest.approx(0.5)


# --- an unmodified Chassis against the simulator in a world ---------------------------------


@pytest.mark.integration
async def test_a_chassis_driven_into_a_wall_sees_its_bumper_and_stopped_wheels() -> None:
    from chassis_sdk import Chassis

    async with (
        ChassisSimulator(world=World.arena(2, 2)) as sim,
        Chassis(sim.port, command_timeout=None) as robot,
    ):
        await robot.set_velocity(0.5, 0.0)  # the watchdog resends it until it is refused
        with anyio.fail_after(10):
            async for t in robot.telemetry():
                if ChassisStatus.FRONT_BUMPER in t.status:
                    break
        assert "FRONT_BUMPER" in robot.motion_blocked()
        assert t.wheels == (0.0, 0.0, 0.0, 0.0)
        assert t.linear == 0.0
        drives = [c.linear_mm for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]
        # 0.5 m/s was what it was driven at into the wall; the hit's block then writes a
        # zero (it may be on its way through the line, or here already), and nothing else.
        assert [mm for mm in drives if mm] == [500] * len([mm for mm in drives if mm])
        assert drives[-1] in (0, 500)
        x, _, _ = sim.firmware.true_pose
        assert x == pytest.approx(1.0 - sim.firmware.footprint[0] / 2, abs=1e-3)
