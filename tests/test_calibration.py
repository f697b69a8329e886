"""Calibrated odometry: :class:`Calibration`, the devices' ``calibration=`` (odometry
and wheel-mode frames), the simulators' miscalibration, and ``chassis-sdk calibrate``
in a subprocess against miscalibrated simulators on real ptys: the factors it writes
make the odometry match the simulator's truth within 1 % on a fresh drive.

Run with ``-s`` to see the recovered factors against the true ones.
"""

from __future__ import annotations

import asyncio
import math
import os
import signal
from dataclasses import FrozenInstanceError
from pathlib import Path
from typing import Any

import pytest

from chassis_sdk import Board, Calibration, Chassis
from chassis_sdk.cli.info_command import EXIT_FAULT
from chassis_sdk.core.calibration import combined_scale
from chassis_sdk.core.odometry import OdometryIntegrator, wrap_angle
from chassis_sdk.devices.config import load_profile
from chassis_sdk.protocol import DriveVelocity, DriveWheels
from chassis_sdk.sim import BoardSimulator, BoardSpec, ChassisSimulator, ChassisSpec

from .support.cli import CLI, one_line
from .support.helpers import drives, until

#: The miscalibration of the simulated robots: wheels 4 % bigger, 20 % slip in turns.
DIAMETER_ERROR, TURN_SLIP = 0.04, 0.2
TRUE_LINEAR = 1 + DIAMETER_ERROR
TRUE_ANGULAR = (1 + DIAMETER_ERROR) * (1 - TURN_SLIP)


# --- Calibration ----------------------------------------------------------------------------


def test_defaults_are_the_identity() -> None:
    cal = Calibration()
    assert (cal.linear_scale, cal.angular_scale) == (1.0, 1.0)
    assert cal.is_identity
    assert not Calibration(1.01).is_identity
    assert cal.linear(0.3) == 0.3
    assert cal.angular(-0.7) == -0.7


def test_factors_multiply_what_is_reported_and_divide_wheel_commands() -> None:
    cal = Calibration(linear_scale=1.25, angular_scale=0.8)
    assert cal.linear(0.4) == pytest.approx(0.5)
    assert cal.angular(1.0) == pytest.approx(0.8)
    assert cal.wheel_command(0.5) == pytest.approx(0.4)
    assert isinstance(Calibration(1, 2).linear_scale, float)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        pytest.param({"linear_scale": math.nan}, "finite", id="nan"),
        pytest.param({"angular_scale": math.inf}, "finite", id="inf"),
        pytest.param({"linear_scale": 0.49}, "0.5 to 2", id="too-small"),
        pytest.param({"angular_scale": 2.01}, "0.5 to 2", id="too-large"),
        pytest.param({"linear_scale": -1.0}, "0.5 to 2", id="negative"),
    ],
)
def test_bad_factors_are_refused(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Calibration(**kwargs)


@pytest.mark.parametrize("value", [True, "1.0", None], ids=["bool", "string", "none"])
def test_factors_that_are_not_numbers_are_refused(value: object) -> None:
    # check_real's refusal of a wrong type (TypeError where the validation says so).
    with pytest.raises((TypeError, ValueError), match="linear_scale must be a number"):
        Calibration(linear_scale=value)  # type: ignore[arg-type]


def test_calibration_is_frozen() -> None:
    cal = Calibration()
    with pytest.raises(FrozenInstanceError):
        cal.linear_scale = 2.0  # type: ignore[misc]


def test_a_new_factor_combines_with_the_one_in_use() -> None:
    # Uncalibrated: the odometry said 1.923 m where 2 m were driven.
    first = combined_scale(1.0, 1.923, 2.0, "linear_scale")
    assert first == pytest.approx(2.0 / 1.923)
    # Calibrated with it, the odometry says 2 m for 2 m: the factor stays.
    assert combined_scale(first, 2.0, 2.0, "linear_scale") == pytest.approx(first)
    # Still 1 % short: the factor grows by 1 %, from the one in use.
    assert combined_scale(first, 1.98, 2.0, "linear_scale") == pytest.approx(first * 2 / 1.98)


@pytest.mark.parametrize(
    ("reported", "measured", "message"),
    [
        pytest.param(1.0, 0.0, "measured must be", id="measured-zero"),
        pytest.param(1.0, -2.0, "measured must be", id="measured-negative"),
        pytest.param(0.0, 1.0, "reported must be", id="reported-zero"),
        pytest.param(1.0, math.nan, "finite", id="measured-nan"),
        pytest.param(1.0, 2.5, "not believable", id="factor-too-large"),
        pytest.param(2.0, 0.9, "not believable", id="factor-too-small"),
    ],
)
def test_unbelievable_measurements_are_refused(
    reported: float, measured: float, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        combined_scale(1.0, reported, measured, "linear_scale")


def test_the_device_keyword_and_property() -> None:
    cal = Calibration(1.1, 0.9)
    assert Chassis("/dev/null", calibration=cal).calibration is cal
    assert Board("/dev/null", calibration=cal).calibration is cal
    robot = Chassis("/dev/null")
    assert robot.calibration == Calibration()
    robot.calibration = cal
    assert robot.calibration is cal
    robot.calibration = None
    assert robot.calibration == Calibration()
    with pytest.raises(TypeError, match="calibration must be a Calibration"):
        Chassis("/dev/null", calibration=1.04)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="calibration must be a Calibration"):
        robot.calibration = {"linear_scale": 1.04}  # type: ignore[assignment]


def test_simulator_specs_refuse_nonsense_miscalibration() -> None:
    with pytest.raises(ValueError, match="wheel_diameter_error"):
        ChassisSpec(wheel_diameter_error=math.nan)
    with pytest.raises(ValueError, match="turn_slip"):
        BoardSpec(turn_slip=1.5)


# --- odometry and wheel-mode commands through a real pty -----------------------------------


@pytest.mark.integration
async def test_odometry_is_the_telemetry_scaled_and_integrated() -> None:
    """Every odometry sample's velocities are the telemetry's times the factors, and
    the pose is those samples integrated."""
    cal = Calibration(linear_scale=1.2, angular_scale=0.75)
    async with ChassisSimulator() as sim, Chassis(sim.port, calibration=cal) as robot:
        telemetry = robot.telemetry()
        odometry = robot.odometry()
        reference = OdometryIntegrator()
        await robot.set_velocity(0.3, 0.6, duration=1.0)
        pairs = 0
        async with asyncio.timeout(5):
            while pairs < 40:
                t, pose = await anext(telemetry), await anext(odometry)
                assert pose.timestamp == t.timestamp
                assert pose.linear == pytest.approx(t.linear * 1.2)
                assert pose.angular == pytest.approx(t.angular * 0.75)
                expected = reference.update(t.linear * 1.2, t.angular * 0.75, t.timestamp)
                assert (pose.x, pose.y, pose.heading) == pytest.approx(
                    (expected.x, expected.y, expected.heading), abs=1e-9
                )
                pairs += 1
        assert pose.linear > 0.1
        assert pose.angular > 0.1  # it moved while compared


@pytest.mark.integration
async def test_wheel_mode_frames_are_divided_by_the_linear_scale() -> None:
    """On the wire (as the firmware decodes the frames), each wheel speed asked is
    divided by the linear scale; with the simulator's wheels that much bigger, the
    robot's true speed is the one asked for. Velocity mode is written as asked."""
    spec = ChassisSpec(wheel_diameter_error=0.25)
    cal = Calibration(linear_scale=1.25, angular_scale=1.25)  # no slip: turns 1.25 x too
    async with ChassisSimulator(spec) as sim, Chassis(sim.port, calibration=cal) as robot:
        await robot.set_wheel_speeds(0.5, -0.25, duration=0.3)
        await until(lambda: any(isinstance(c, DriveWheels) for _, c in sim.firmware.received))
        wheels = [c for _, c in sim.firmware.received if isinstance(c, DriveWheels)]
        assert (wheels[0].left_mm, wheels[0].right_mm) == (400, -200)
        assert robot.commanded_velocity == (0.5, -0.25)  # as asked
        await until(lambda: robot.commanded_velocity is None, timeout=3)
        # Cruising at a true 0.4 m/s: the wheels (as their encoders count) turn at
        # 0.32 m/s, which on wheels 1.25 x bigger is 0.4 m/s over the ground.
        await robot.set_wheel_speeds(0.4, 0.4, duration=1.0)
        fw = sim.firmware
        await until(lambda: fw.wheels[0] == pytest.approx(0.32), timeout=3)
        true_speed = fw.wheels[0] * (1 + spec.wheel_diameter_error)
        print(f"\nwheel mode asked 0.4 m/s: true speed {true_speed:.4f} m/s")
        assert true_speed == pytest.approx(0.4, abs=0.001)
        await until(lambda: robot.commanded_velocity is None, timeout=3)
        await until(lambda: abs(fw.wheels[0]) < 1e-9, timeout=3)
        await until(lambda: robot.latest_odometry.linear == 0, timeout=3)  # type: ignore[union-attr]
        reported = robot.latest_odometry
        assert reported is not None
        # And the calibrated odometry is where the robot truly is.
        x, y, heading = sim.firmware.pose
        assert (reported.x, reported.y) == pytest.approx((x, y), rel=0.01, abs=0.002)
        # 2 %: odometry integrates on the host's receive times, and under CI's load
        # (six workers on two cores) this 0.3 s turn's heading erred by up to 1.3 %
        # (once in about ten runs, before and after the burst fix alike); a wrong
        # calibration scale errs by 25 %.
        assert reported.heading == pytest.approx(heading, rel=0.02)


@pytest.mark.integration
@pytest.mark.slow
async def test_miscalibrated_simulator_without_calibration_is_off_by_the_true_factors() -> None:
    """The simulators' miscalibration is what it says (so the tests below can fail):
    uncalibrated odometry falls short by 1 / 1.04 and over-turns by 1 / 0.832."""
    spec = ChassisSpec(wheel_diameter_error=DIAMETER_ERROR, turn_slip=TURN_SLIP)
    async with ChassisSimulator(spec) as sim, Chassis(sim.port) as robot:
        await robot.configure_odometry()
        distance, turned = await _drive_and_compare(robot, sim)
    print(f"\nuncalibrated: {distance * TRUE_LINEAR:.5f} {turned * TRUE_ANGULAR:.5f}")
    assert distance == pytest.approx(1 / TRUE_LINEAR, rel=0.005)
    assert turned == pytest.approx(1 / TRUE_ANGULAR, rel=0.005)


class Tracked:
    """The odometry's path length and unwrapped rotation since it was started, from
    the device's ``odometry()`` samples (the pose's heading is wrapped)."""

    def __init__(self, robot: Any) -> None:
        self.robot = robot
        self.path = self.turned = 0.0
        self.latest: Any = None

    async def run(self) -> None:
        previous = None
        async for pose in self.robot.odometry():
            if previous is not None:
                self.path += math.hypot(pose.x - previous.x, pose.y - previous.y)
                self.turned += wrap_angle(pose.heading - previous.heading)
            previous = self.latest = pose

    async def standstill(self) -> None:
        def still() -> bool:
            pose = self.latest
            return pose is not None and abs(pose.linear) < 1e-3 and abs(pose.angular) < 1e-3

        await until(still, timeout=5)
        stamp = self.latest.timestamp  # one more sample at rest: the pose is final
        await until(lambda: self.latest.timestamp > stamp, timeout=2)


async def _drive_and_compare(robot: Any, sim: Any) -> tuple[float, float]:
    """A fresh drive (1 m straight, then about half a turn in place): the odometry's
    distance and rotation, each over the simulator's true ones."""
    fw = sim.firmware
    tracked = Tracked(robot)
    task = asyncio.create_task(tracked.run())
    try:
        await until(lambda: tracked.latest is not None)
        path0, odometer0 = tracked.path, fw.odometer
        await robot.set_velocity(0.3, 0.0, duration=1.0 / 0.3)
        await until(lambda: robot.commanded_velocity is None, timeout=10)
        await tracked.standstill()
        distance = (tracked.path - path0) / (fw.odometer - odometer0)
        turned0, heading0 = tracked.turned, fw.pose[2]
        await robot.set_velocity(0.0, 1.0, duration=3.0)
        await until(lambda: robot.commanded_velocity is None, timeout=10)
        await tracked.standstill()
        turned = (tracked.turned - turned0) / (fw.pose[2] - heading0)
    finally:
        task.cancel()
    return distance, turned


# --- chassis-sdk calibrate against miscalibrated simulators ----------------------------------


class Cli:
    """``chassis-sdk calibrate`` in a subprocess, answering its prompt on stdin."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.out = ""

    @classmethod
    async def start(cls, *args: str, home: Path) -> Cli:
        env = {**os.environ, "XDG_CONFIG_HOME": str(home), "HOME": str(home)}
        env.pop("CHASSIS_SDK_CONFIG", None)
        proc = await asyncio.create_subprocess_exec(
            *CLI, "calibrate", *args,
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, cwd=home, env=env,
        )  # fmt: skip
        return cls(proc)

    async def prompt(self, timeout: float = 60.0) -> None:
        """Wait until the command asks for the measurement (the robot has stopped)."""
        assert self.proc.stdout is not None
        async with asyncio.timeout(timeout):
            while "really" not in self.out.rsplit("\n", 1)[-1]:
                chunk = await self.proc.stdout.read(4096)
                if not chunk:
                    raise AssertionError(f"ended before the prompt: {self.out}")
                self.out += chunk.decode()

    async def finish(self, answer: str | None = None, timeout: float = 60.0) -> tuple[int, str]:
        data = None if answer is None else f"{answer}\n".encode()
        async with asyncio.timeout(timeout):
            out, err = await self.proc.communicate(data)
        self.out += out.decode()
        assert self.proc.returncode is not None
        return self.proc.returncode, err.decode()


@pytest.mark.integration
@pytest.mark.slow
async def test_calibrate_recovers_the_chassis_factors(tmp_path: Path) -> None:
    """linear then angular, the operator answering with the simulator's truth; then
    linear again, which keeps the factor (it converges); then a fresh drive with the
    written factors matches the truth within 1 %."""
    spec = ChassisSpec(wheel_diameter_error=DIAMETER_ERROR, turn_slip=TURN_SLIP)
    profile = tmp_path / "robot.toml"
    profile.write_text('# my robot\n[robot]\ndevice = "chassis"\n')
    linear_factors = []
    async with ChassisSimulator(spec) as sim:
        fw = sim.firmware
        for _ in range(2):
            odometer = fw.odometer
            run = await Cli.start(
                sim.port, "linear", "--distance", "1", "--speed", "0.3",
                "--write", str(profile), home=tmp_path,
            )  # fmt: skip
            await run.prompt()
            code, err = await run.finish(f"{fw.odometer - odometer:.5f}")
            assert code == 0, err
            assert "odometry measured" in run.out
            assert "written" in run.out
            linear_factors.append(load_profile(profile).calibration.linear_scale)  # type: ignore[union-attr]
        heading = fw.pose[2]
        run = await Cli.start(
            sim.port, "angular", "--turns", "1", "--speed", "1.0",
            "--write", str(profile), home=tmp_path,
        )  # fmt: skip
        await run.prompt()
        code, err = await run.finish(f"{(fw.pose[2] - heading) / math.tau:.5f}")
        assert code == 0, err
        cal = load_profile(profile).calibration
        assert cal is not None
        assert "# my robot" in profile.read_text()  # the operator's comments are kept
        async with Chassis(sim.port, calibration=cal) as robot:
            distance, turned = await _drive_and_compare(robot, sim)
    print(
        f"\nchassis: linear_scale {linear_factors[0]:.4f} then {linear_factors[1]:.4f} "
        f"(true {TRUE_LINEAR:.4f}), angular_scale {cal.angular_scale:.4f} (true "
        f"{TRUE_ANGULAR:.4f}); fresh drive: distance {100 * (distance - 1):+.2f} %, "
        f"rotation {100 * (turned - 1):+.2f} % of the truth"
    )
    assert linear_factors[0] == pytest.approx(TRUE_LINEAR, rel=0.01)
    assert linear_factors[1] == pytest.approx(linear_factors[0], rel=0.005)
    assert cal.angular_scale == pytest.approx(TRUE_ANGULAR, rel=0.01)
    assert distance == pytest.approx(1.0, rel=0.01)
    assert turned == pytest.approx(1.0, rel=0.01)


@pytest.mark.integration
@pytest.mark.slow
async def test_calibrate_fits_the_board_from_its_gyro(tmp_path: Path) -> None:
    """A board's angular factor comes from its gyro (which does not slip), with no
    prompt; with it, the velocity odometry turns as the board truly did."""
    spec = BoardSpec(wheel_diameter_error=DIAMETER_ERROR, turn_slip=TURN_SLIP)
    profile = tmp_path / "board.toml"
    async with BoardSimulator(spec) as sim:
        run = await Cli.start(
            sim.port, "angular", "--device", "board", "--turns", "1", "--speed", "1.0",
            "--write", str(profile), home=tmp_path,
        )  # fmt: skip
        code, err = await run.finish(timeout=60)
        assert code == 0, err
        assert "the gyro measured" in run.out
        assert "really" not in run.out
        cal = load_profile(profile).calibration
        assert cal is not None
        assert cal.linear_scale == 1.0
        async with Board(sim.port, calibration=cal) as board:
            _, turned = await _drive_and_compare(board, sim)
    print(
        f"\nboard (gyro): angular_scale {cal.angular_scale:.4f} (true {TRUE_ANGULAR:.4f}); "
        f"fresh turn {100 * (turned - 1):+.2f} % of the truth"
    )
    assert cal.angular_scale == pytest.approx(TRUE_ANGULAR, rel=0.01)
    assert turned == pytest.approx(1.0, rel=0.01)


@pytest.mark.integration
async def test_measured_on_the_command_line_and_dry_run(tmp_path: Path) -> None:
    """--measured skips the prompt; --dry-run prints the factor and writes nothing."""
    async with ChassisSimulator() as sim:
        run = await Cli.start(
            sim.port, "linear", "--distance", "0.3", "--speed", "0.3", "--measured", "0.33",
            "--dry-run", "--write", str(tmp_path / "x.toml"), home=tmp_path,
        )  # fmt: skip
        code, err = await run.finish()
    assert code == 0, err
    assert "really" not in run.out
    assert "not written (--dry-run)" in run.out
    reported = float(run.out.split("odometry measured ")[1].split(" m")[0])
    factor = float(run.out.split("linear_scale 1.00000 -> ")[1].split()[0])
    assert factor == pytest.approx(0.33 / reported, abs=3e-4)
    assert not (tmp_path / "x.toml").exists()


@pytest.mark.integration
async def test_a_robot_that_does_not_move_fails_in_one_line(tmp_path: Path) -> None:
    # A robot whose wheels are blocked by what it reports (its hardware e-stop) is
    # refused before it is driven: one line says what and what to do; nothing moves.
    async with ChassisSimulator() as sim:
        sim.firmware.set_hardware_estop(True)
        run = await Cli.start(
            sim.port, "linear", "--measured", "2", "--write", str(tmp_path / "x.toml"),
            home=tmp_path,
        )  # fmt: skip
        code, err = await run.finish()
        stops = sim.firmware.received
    assert code == EXIT_FAULT
    assert "e-stopped (hardware button); release the button" in one_line(err)
    assert not (tmp_path / "x.toml").exists()
    drives = [c for _, c in stops if isinstance(c, DriveVelocity)]
    assert all(d.linear_mm == 0 for d in drives)  # refused, not driven


@pytest.mark.integration
async def test_no_telemetry_fails_in_one_line(tmp_path: Path) -> None:
    async with ChassisSimulator() as sim:
        sim.firmware.telemetry_enabled = False
        run = await Cli.start(
            sim.port, "angular", "--timeout", "0.5", "--measured", "5",
            "--write", str(tmp_path / "x.toml"), home=tmp_path,
        )  # fmt: skip
        code, err = await run.finish()
    assert code != 0
    assert "within 0.5 s" in one_line(err)
    assert not (tmp_path / "x.toml").exists()


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "answer", "message", "moved"),
    [
        pytest.param(("--measured", "0"), None, "--measured must be > 0", False, id="measured-zero"),
        pytest.param((), "abc", "'abc' is not a number", True, id="not-a-number"),
        pytest.param((), "", "no measurement entered", True, id="empty-answer"),
        # Known before the drive (the odometry reports --distance): refused before it
        # (issue 44, item 9), in the words of the flags typed.
        pytest.param(("--measured", "30"), None, "--measured 30 m against --distance 0.2: linear_scale would be 150.000, outside 0.5..2, so the measurement is not believable; nothing driven", False, id="factor-out-of-range"),
        pytest.param(("--measured", "10", "--no-imu"), None, "--measured 10 turns against --turns 0.1: angular_scale would be 100.000", False, id="turns-out-of-range"),
        pytest.param(("--imu",), None, "has no gyro", False, id="imu-on-a-chassis"),
    ],
)  # fmt: skip
async def test_nonsense_fails_in_one_line_and_writes_nothing(
    tmp_path: Path, args: tuple[str, ...], answer: str | None, message: str, moved: bool
) -> None:
    what = "angular" if "--imu" in args or "--no-imu" in args else "linear"
    async with ChassisSimulator() as sim:
        run = await Cli.start(
            sim.port, what, "--distance", "0.2", "--turns", "0.1", "--speed", "0.4", *args,
            "--write", str(tmp_path / "x.toml"), home=tmp_path,
        )  # fmt: skip
        if answer is not None:
            await run.prompt()
        code, err = await run.finish(answer)
        driven = any(v.linear_mm or v.angular for v in drives(sim))
    assert code != 0
    assert message in one_line(err)
    assert not (tmp_path / "x.toml").exists()
    assert driven == moved


@pytest.mark.integration
async def test_ctrl_c_stops_the_robot_and_writes_nothing(tmp_path: Path) -> None:
    async with ChassisSimulator() as sim:
        fw = sim.firmware
        run = await Cli.start(
            sim.port, "linear", "--distance", "5", "--measured", "5",
            "--write", str(tmp_path / "x.toml"), home=tmp_path,
        )  # fmt: skip
        await until(lambda: fw.odometer > 0.05, timeout=20)
        run.proc.send_signal(signal.SIGINT)
        code, err = await run.finish()
        drives = [c for _, c in fw.received if isinstance(c, DriveVelocity)]
    assert code == 130, err
    assert drives[-1] == DriveVelocity(0, 0.0)  # zero is the last velocity frame
    assert fw.odometer < 1.0
    assert not (tmp_path / "x.toml").exists()


@pytest.mark.integration
async def test_calibrate_linear_on_a_board(tmp_path: Path) -> None:
    """A board's linear factor, the operator answering with the truth (20 Hz velocity
    feedback, not the chassis's 50 Hz telemetry)."""
    spec = BoardSpec(wheel_diameter_error=DIAMETER_ERROR, turn_slip=TURN_SLIP)
    profile = tmp_path / "board.toml"
    async with BoardSimulator(spec) as sim:
        fw = sim.firmware
        odometer = fw.odometer
        run = await Cli.start(
            sim.port, "linear", "--device", "board", "--distance", "1", "--speed", "0.3",
            "--write", str(profile), home=tmp_path,
        )  # fmt: skip
        await run.prompt()
        code, err = await run.finish(f"{fw.odometer - odometer:.5f}")
    assert code == 0, err
    cal = load_profile(profile).calibration
    assert cal is not None
    print(f"\nboard: linear_scale {cal.linear_scale:.4f} (true {TRUE_LINEAR:.4f})")
    assert cal.linear_scale == pytest.approx(TRUE_LINEAR, rel=0.01)
    assert cal.angular_scale == 1.0


@pytest.mark.integration
async def test_calibrate_drives_within_the_profiles_ramp_and_deadman(tmp_path: Path) -> None:
    """The profile's [limits] acceleration and [deadman] reach calibrate's device (it
    built its own limits from the speed flags alone)."""
    (tmp_path / "chassis-sdk.toml").write_text(
        "[limits]\nlinear_acceleration = 0.2\n[deadman]\ncommand_timeout = 0.3\n"
    )
    async with ChassisSimulator() as sim:
        run = await Cli.start(
            sim.port, "linear", "--distance", "0.1", "--speed", "0.2", "--measured", "0.1",
            "--dry-run", home=tmp_path,
        )  # fmt: skip
        code, err = await run.finish()
        drives = [c for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]
    assert code == 0, err
    moving = [d.linear_mm for d in drives if d.linear_mm]
    assert moving[0] <= 30  # ramped at 0.2 m/s² (one 50 ms step is 10 mm/s), not a jump to 200
    assert max(moving) >= 190  # up to the speed asked (the ramp's last step may round)
