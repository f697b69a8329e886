"""A sans-IO model of the protocol B controller-board firmware.

The simulator that serves it is `chassis_sdk.sim.BoardSimulator`.

IMU at 100 Hz following the motion (gravity on z, gyro z the angular rate, small
noise), velocity feedback at 20 Hz following the commands through a ramp, battery at
1 Hz, log lines on events, LED and buzzer state with replies carrying the request id,
PWM and servo commands accepted, and the same 0.5 s firmware command timeout as the
chassis.

It can be miscalibrated as a real base is (``BoardSpec.wheel_diameter_error``,
``BoardSpec.turn_slip``): the velocity feedback reports what the encoders count, while
the gyro (which does not slip) and the true pose (`BoardFirmware.pose`,
`BoardFirmware.odometer`) follow where the robot really went.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from ...core.firmware import FirmwareModel, next_slot
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

__all__ = ["BoardFirmware", "BoardSpec"]

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

    def __post_init__(self) -> None:
        check_real(self.wheel_diameter_error, "wheel_diameter_error", low=-0.5, high=0.5)
        check_real(self.turn_slip, "turn_slip", low=0, high=0.9)


class BoardFirmware(FirmwareModel[BoardCommand]):
    """The board firmware model: ``receive(bytes, now)`` and ``poll(now)`` return bytes.

    A reset (`reset`) comes up with the LED and buzzer off, the motors stopped
    and a "board ready" log line.
    """

    def __init__(self, spec: BoardSpec | None = None) -> None:
        super().__init__()
        self.spec = spec or BoardSpec()
        self._rng = random.Random(self.spec.seed)
        self._battery = self.spec.battery_full  # the battery outlives a reset
        #: The pack model (``spec.pack``), or ``None``; its ``charge`` is the truth.
        self.pack = None if self.spec.pack is None else Pack(self.spec.pack)
        #: The true pose (x m, y m, heading rad unwrapped) from the simulated motion
        #: (with ``spec.wheel_diameter_error`` and ``spec.turn_slip``).
        self.pose = (0.0, 0.0, 0.0)
        #: The true distance travelled (m, forward and back both count).
        self.odometer = 0.0
        self._power_on()

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
        dv = _clamp(tv - self.linear, self.spec.max_linear_acceleration * dt)
        dw = _clamp(tw - self.angular, self.spec.max_angular_acceleration * dt)
        self.linear += dv
        self.angular += dw
        self._linear_accel = dv / dt
        v, w = self.true_linear, self.true_angular
        mid = self.heading + w * elapsed / 2
        x, y, h = self.pose
        self.pose = (
            x + v * elapsed * math.cos(mid),
            y + v * elapsed * math.sin(mid),
            h + w * elapsed,
        )
        self.odometer += abs(v) * elapsed
        self.heading = (self.heading + w * elapsed) % (2 * math.pi)
        moving = abs(self.linear) > 1e-6 or abs(self.angular) > 1e-6
        if self.pack is not None:
            self.pack.draw(self._load(), dt)
        elif moving:
            self._battery -= 0.0002 * dt

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
        accel = Vector3(
            self._linear_accel * true / _G + g(0, an),
            v * w / _G + g(0, an),
            1.0 + g(0, an),
        )
        gyro = Vector3(g(0, gn), g(0, gn), math.degrees(w) + g(0, gn))
        mag = Vector3(
            round(300 * math.cos(self.heading)), round(-300 * math.sin(self.heading)), -420.0
        )
        return ImuSample(accel, gyro, mag)


def _clamp(x: float, limit: float) -> float:
    return max(-limit, min(limit, x))
