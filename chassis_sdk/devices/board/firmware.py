"""A sans-IO model of the protocol B controller-board firmware.

The simulator that serves it is `chassis_sdk.sim.BoardSimulator`.

IMU at 100 Hz following the motion (gravity on z, gyro z the angular rate, small
noise), velocity feedback at 20 Hz following the commands through a ramp, battery at
1 Hz, log lines on events, LED and buzzer state with replies carrying the request id,
PWM and servo commands accepted, and the same 0.5 s firmware command timeout as the
chassis.

It can be miscalibrated as a real base is (``BoardSpec.wheel_diameter_error``,
``BoardSpec.turn_slip``, a random slip ``BoardSpec.slip_noise``): the velocity feedback
reports what the encoders count, while the gyro (which does not slip) and the true pose
(`BoardFirmware.true_pose`, `BoardFirmware.odometer`) follow where the robot really
went.

With a world (``BoardFirmware(world=...)``, a `chassis_sdk.sim.World` or anything that
has its ``sweep``), the robot is a box (``BoardSpec.footprint``) that stops at the
walls: running into one stops the wheels (the velocity feedback reads 0 while a
velocity is commanded) and the IMU's next sample shows the impact, a spike of
deceleration on x. ``stall_wheels`` holds the wheels still for a while; ``set_tilt``
tilts the board (the accelerometer shows gravity off the z axis).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from ...core.firmware import FirmwareModel, Obstacles, check_fits, check_motion, next_slot
from ...core.pack import Pack, PackSpec
from ...core.validation import check_real
from .messages import (
    BatteryReading,
    BoardCommand,
    BuzzerCommand,
    BuzzerReply,
    ImuSample,
    LedCommand,
    LedReply,
    LogMessage,
    MotorPwmCommand,
    ServoCommand,
    SwitchAction,
    Vector3,
    VelocityCommand,
    VelocityFeedback,
)
from .protocol import BoardCommandDecoder, BoardEncoder

__all__ = ["BoardFirmware", "BoardSpec", "Obstacles"]

_G = 9.80665


@dataclass(slots=True)
class BoardSpec:
    """Rates and dynamics of the simulated board."""

    imu_period: float = 0.01
    velocity_period: float = 0.05
    battery_period: float = 1.0
    command_timeout: float = 0.5
    max_linear_acceleration: float = 1.0  #: m/s²
    max_angular_acceleration: float = 3.0  #: rad/s²
    battery_full: float = 12.6  #: V
    accel_noise: float = 0.005  #: g, standard deviation
    gyro_noise: float = 0.05  #: deg/s, standard deviation
    seed: int = 0
    #: A pack model instead of the linear battery (its charge drains with the load's
    #: current, its voltage follows the chemistry's curve and sags by ``I * R``);
    #: ``None``: the linear battery, as before.
    pack: PackSpec | None = None
    #: The true wheels' diameter over the one the firmware believes, minus 1: the
    #: robot moves ``1 + wheel_diameter_error`` times what the velocity feedback says.
    wheel_diameter_error: float = 0.0
    #: Skid slip in turns: the robot turns ``1 - turn_slip`` times what the wheels
    #: say (after the diameter error); the gyro reports the true rate.
    turn_slip: float = 0.0
    #: Random slip: each physics step the true motion (forward and turning, each on its
    #: own) is ``1 + N(0, slip_noise)`` times what the wheels say (0.01: 1 %); 0: none.
    #: Drawn from its own generator (seeded by ``seed``): the IMU's noise stays the same.
    slip_noise: float = 0.0
    #: The robot's box in a world, ``(length, width)`` in metres.
    footprint: tuple[float, float] = (0.3, 0.25)

    def __post_init__(self) -> None:
        check_motion(self.wheel_diameter_error, self.turn_slip, self.slip_noise, self.footprint)


class BoardFirmware(FirmwareModel[BoardCommand]):
    """The board firmware model: ``receive(bytes, now)`` and ``poll(now)`` return bytes.

    A reset (`reset`) comes up with the LED and buzzer off, the motors stopped
    and a "board ready" log line.

    Args:
        spec: Rates, dynamics, miscalibration.
        world: Walls to run into (see `world`); ``None``: open space.

    Raises:
        ValueError: The robot at the origin touches a wall of ``world``.
    """

    def __init__(self, spec: BoardSpec | None = None, *, world: Obstacles | None = None) -> None:
        super().__init__()
        self.spec = spec or BoardSpec()
        self._rng = random.Random(self.spec.seed)
        self._slip_rng = random.Random(f"slip:{self.spec.seed}")
        #: Collisions with the world's walls so far.
        self.impacts = 0
        #: The board's tilt (pitch nose up, roll left side up; degrees), which the
        #: accelerometer shows (`set_tilt`).
        self.tilt = (0.0, 0.0)
        self._impact = 0.0  # m/s² on x for the next IMU sample
        self._touching = False  # against a wall at the latest step
        self._stalled_until = -math.inf  # a jammed drive is physical: a reset keeps it
        self._battery = self.spec.battery_full  # the battery outlives a reset
        #: The pack model (``spec.pack``), or ``None``; its ``charge`` is the truth.
        self.pack = None if self.spec.pack is None else Pack(self.spec.pack)
        #: The true pose (x m, y m, heading rad unwrapped) from the simulated motion
        #: (with ``spec.wheel_diameter_error`` and ``spec.turn_slip``).
        self.pose = (0.0, 0.0, 0.0)
        #: The true distance travelled (m, forward and back both count).
        self.odometer = 0.0
        self._world: Obstacles | None = None
        self.world = world
        self._power_on()

    @property
    def world(self) -> Obstacles | None:
        """The walls the robot runs into (``None``: open space). Setting it checks that
        the robot, where it truly is, touches no wall.

        Raises:
            ValueError: (setting) The robot's box touches a wall of the new world.
        """
        return self._world

    @world.setter
    def world(self, world: Obstacles | None) -> None:
        check_fits("the board's robot", world, self.pose, self.spec.footprint)
        self._world = world

    @property
    def true_pose(self) -> tuple[float, float, float]:
        """Where the robot truly is: x, y (m) and heading (rad, unwrapped) from its
        start pose, with the wheels' miscalibration and slip, stopped by walls. The
        velocity feedback (and the host's odometry) reports what the encoders count."""
        return self.pose

    def _power_on(self) -> None:
        self._decoder = BoardCommandDecoder()
        self._encoder = BoardEncoder()
        self.led = False
        self.buzzer = False
        self.pwm = {1: 0, 2: 0, 3: 0, 4: 0}
        self.servo = {1: 0.0, 2: 0.0}
        self.target = (0.0, 0.0)
        self.linear = 0.0
        self.angular = 0.0
        self.heading = 0.0
        self._linear_accel = 0.0
        self._last_command = -math.inf
        self._last_step: float | None = None
        self._next_imu = 0.0
        self._next_velocity = 0.0
        self._next_battery = 0.0
        self._pending_logs: list[str] = []

    # --- sans-IO interface ----------------------------------------------------------------

    def on_connect(self, now: float) -> None:
        """Start the clocks and greet the host with a log line."""
        self._last_step = now
        self._next_imu = self._next_velocity = self._next_battery = now
        self._pending_logs.append("board ready")

    def poll(self, now: float) -> bytes:
        """Advance the model to ``now``; return the periodic frames that fell due."""
        if self.booting(now):
            return b""
        self._step(now)
        enc = self._encoder.encode
        out = bytearray()
        for text in self._pending_logs:
            out += enc(LogMessage(text))
        self._pending_logs.clear()
        if now >= self._next_imu:
            out += enc(self.imu_sample())
            self._next_imu = next_slot(self._next_imu, self.spec.imu_period, now)
        if now >= self._next_velocity:
            out += enc(VelocityFeedback(self.linear, self.angular))
            self._next_velocity = next_slot(self._next_velocity, self.spec.velocity_period, now)
        if now >= self._next_battery:
            out += enc(BatteryReading(round(self.battery_voltage, 2)))
            self._next_battery = next_slot(self._next_battery, self.spec.battery_period, now)
        return bytes(out)

    def next_deadline(self) -> float:
        """When `poll` next has something to send."""
        return min(self._next_imu, self._next_velocity, self._next_battery)

    def set_battery(self, voltage: float) -> None:
        """Set the battery voltage (it keeps draining from there); with a pack model,
        its charge becomes the one this open-circuit voltage shows."""
        self._battery = voltage
        if self.pack is not None:
            self.pack.set_open_voltage(voltage)

    def log(self, text: str) -> None:
        """Queue a log line for the next poll."""
        self._pending_logs.append(text)

    def stall_wheels(self, now: float, seconds: float) -> None:
        """Hold the wheels still from ``now`` for ``seconds`` (0 ends a stall): they are
        commanded but do not turn (the velocity feedback reads 0), as a jammed drive
        would. A reset does not end it."""
        self._stalled_until = now + max(0.0, seconds)

    def stalled(self, now: float) -> bool:
        """True while `stall_wheels` holds the wheels at ``now``."""
        return now < self._stalled_until

    def set_tilt(self, pitch: float, roll: float = 0.0) -> None:
        """Tilt the board ``pitch`` degrees nose up and ``roll`` degrees left side up
        (both 0: level); the accelerometer shows gravity accordingly.

        Raises:
            ValueError: An angle is not a finite number from -180 to 180.
        """
        self.tilt = (
            check_real(pitch, "pitch", low=-180, high=180, unit="°"),
            check_real(roll, "roll", low=-180, high=180, unit="°"),
        )

    # --- commands -----------------------------------------------------------------------------

    def _execute(self, cmd: BoardCommand, now: float) -> bytes:
        if isinstance(cmd, LedCommand | BuzzerCommand):
            is_led = isinstance(cmd, LedCommand)
            name = "led" if is_led else "buzzer"
            if cmd.action is not SwitchAction.READ:
                on = cmd.action is SwitchAction.ON
                if is_led:
                    self.led = on
                else:
                    self.buzzer = on
                self.log(f"{name} {'on' if on else 'off'}")
            state = self.led if is_led else self.buzzer
            reply = (
                LedReply(cmd.request_id, state) if is_led else BuzzerReply(cmd.request_id, state)
            )
            return self._encoder.encode(reply)
        if isinstance(cmd, VelocityCommand):
            self._last_command = now
            self.target = (cmd.linear_milli / 1000, cmd.angular_milli / 1000)
        elif isinstance(cmd, MotorPwmCommand):
            self.pwm[int(cmd.motor)] = cmd.pwm
            self.log(f"motor {int(cmd.motor)} pwm {cmd.pwm}")
        elif isinstance(cmd, ServoCommand):
            self.servo[int(cmd.servo)] = cmd.angle_tenths / 10
            self.log(f"servo {int(cmd.servo)} -> {cmd.angle_tenths / 10:.1f} deg")
        return b""

    # --- physics -----------------------------------------------------------------------------

    def _step(self, now: float) -> None:
        last = self._last_step
        self._last_step = now
        if last is None or now <= last:
            return
        # The physics steps at most 0.1 s; the true pose moves for all the time that
        # passed (up to a second), as the robot would while the model's loop was held
        # up, and as the host's odometry integrates the gap at the next frame's speed.
        elapsed = min(now - last, 1.0)
        dt = min(elapsed, 0.1)
        if now - self._last_command > self.spec.command_timeout:
            if self.target != (0.0, 0.0):
                self.log("command timeout: stopping")
            self.target = (0.0, 0.0)
        tv, tw = self.target
        if self.stalled(now):
            dv, dw = -self.linear, -self.angular  # held: the wheels do not turn
        else:
            dv = _clamp(tv - self.linear, self.spec.max_linear_acceleration * dt)
            dw = _clamp(tw - self.angular, self.spec.max_angular_acceleration * dt)
        self.linear += dv
        self.angular += dw
        self._linear_accel = dv / dt
        v, w = self.true_linear, self.true_angular
        if self.spec.slip_noise and (v or w):
            gauss, sigma = self._slip_rng.gauss, self.spec.slip_noise
            v, w = v * (1.0 + gauss(0.0, sigma)), w * (1.0 + gauss(0.0, sigma))
        mid = self.heading + w * elapsed / 2
        x, y, h = start = self.pose
        end = (x + v * elapsed * math.cos(mid), y + v * elapsed * math.sin(mid), h + w * elapsed)
        touching = False
        if self._world is not None and end != start:
            end, touch = self._world.sweep(start, end, *self.spec.footprint)
            touching = touch is not None
            if touching:
                self._hit(v)
                v = math.hypot(end[0] - x, end[1] - y) / elapsed
                w = (end[2] - h) / elapsed
        self._touching = touching
        self.pose = end
        self.odometer += abs(v) * elapsed
        self.heading = (self.heading + w * elapsed) % (2 * math.pi)
        moving = abs(self.linear) > 1e-6 or abs(self.angular) > 1e-6
        if self.pack is not None:
            self.pack.draw(self._load(), dt)
        elif moving:
            self._battery -= 0.0002 * dt

    def _hit(self, true_linear: float) -> None:
        """The robot ran into a wall: the wheels stop at once; a new contact (not one
        pushed against since the last step) shows on the IMU as the deceleration of
        stopping from ``true_linear`` within one IMU period."""
        if not self._touching:
            self.impacts += 1
            self._impact = -true_linear / self.spec.imu_period
        self.linear = self.angular = 0.0
        self._linear_accel = 0.0

    @property
    def true_linear(self) -> float:
        """The robot's true linear velocity (m/s): the encoders' with the diameter error."""
        return self.linear * (1.0 + self.spec.wheel_diameter_error)

    @property
    def true_angular(self) -> float:
        """The robot's true turn rate (rad/s), which the gyro measures."""
        spec = self.spec
        return self.angular * (1.0 + spec.wheel_diameter_error) * (1.0 - spec.turn_slip)

    def _load(self) -> float:
        """The current drawn (A): the electronics and the motion."""
        return 0.5 + 4 * abs(self.linear) + 1 * abs(self.angular)

    @property
    def battery_voltage(self) -> float:
        """Terminal voltage, sagging with the motion."""
        if self.pack is not None:
            return self.pack.terminal_voltage(self._load())
        return self._battery - 0.05 * self._load()

    @property
    def battery_charge(self) -> float | None:
        """The pack model's true state of charge (percent), or ``None`` without one."""
        return None if self.pack is None else self.pack.charge

    def imu_sample(self) -> ImuSample:
        """An IMU sample for the current motion (accel in g, gyro in deg/s, mag raw)."""
        g = self._rng.gauss
        an, gn = self.spec.accel_noise, self.spec.gyro_noise
        # Centripetal acceleration v*w points to the left (+y) when turning left.
        true = 1.0 + self.spec.wheel_diameter_error
        v, w = self.true_linear, self.true_angular
        pitch, roll = (math.radians(a) for a in self.tilt)
        # Gravity as the accelerometer feels it (an upward push) on the tilted board;
        # level: (0, 0, 1) g, as before.
        up = (math.sin(pitch), math.cos(pitch) * math.sin(roll), math.cos(pitch) * math.cos(roll))
        impact, self._impact = self._impact, 0.0
        accel = Vector3(
            (self._linear_accel * true + impact) / _G + up[0] + g(0, an),
            v * w / _G + up[1] + g(0, an),
            up[2] + g(0, an),
        )
        gyro = Vector3(g(0, gn), g(0, gn), math.degrees(w) + g(0, gn))
        mag = Vector3(
            round(300 * math.cos(self.heading)), round(-300 * math.sin(self.heading)), -420.0
        )
        return ImuSample(accel, gyro, mag)


def _clamp(x: float, limit: float) -> float:
    return max(-limit, min(limit, x))
