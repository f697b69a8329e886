"""A sans-IO model of the protocol B controller-board firmware.

The simulator that serves it is :class:`chassis_sdk.sim.BoardSimulator`.

IMU at 100 Hz following the motion (gravity on z, gyro z the angular rate, small
noise), velocity feedback at 20 Hz following the commands through a ramp, battery at
1 Hz, log lines on events, LED and buzzer state with replies carrying the request id,
PWM and servo commands accepted, and the same 0.5 s firmware command timeout as the
chassis.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from ...core.firmware import FirmwareModel, next_slot
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


class BoardFirmware(FirmwareModel[BoardCommand]):
    """The board firmware model: ``receive(bytes, now)`` and ``poll(now)`` return bytes.

    A reset (:meth:`reset`) comes up with the LED and buzzer off, the motors stopped
    and a "board ready" log line.
    """

    def __init__(self, spec: BoardSpec | None = None) -> None:
        super().__init__()
        self.spec = spec or BoardSpec()
        self._rng = random.Random(self.spec.seed)
        self._battery = self.spec.battery_full  # the battery outlives a reset
        #: The true pose (x m, y m, heading rad unwrapped) from the simulated motion.
        self.pose = (0.0, 0.0, 0.0)
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
        """When :meth:`poll` next has something to send."""
        return min(self._next_imu, self._next_velocity, self._next_battery)

    def set_battery(self, voltage: float) -> None:
        """Set the battery voltage (it keeps draining from there)."""
        self._battery = voltage

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
        dt = min(now - last, 0.1)
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
        mid = self.heading + self.angular * dt / 2
        x, y, h = self.pose
        self.pose = (
            x + self.linear * dt * math.cos(mid),
            y + self.linear * dt * math.sin(mid),
            h + self.angular * dt,
        )
        self.heading = (self.heading + self.angular * dt) % (2 * math.pi)
        moving = abs(self.linear) > 1e-6 or abs(self.angular) > 1e-6
        if moving:
            self._battery -= 0.0002 * dt

    @property
    def battery_voltage(self) -> float:
        """Terminal voltage, sagging with the motion."""
        load = 0.5 + 4 * abs(self.linear) + 1 * abs(self.angular)
        return self._battery - 0.05 * load

    def imu_sample(self) -> ImuSample:
        """An IMU sample for the current motion (accel in g, gyro in deg/s, mag raw)."""
        g = self._rng.gauss
        an, gn = self.spec.accel_noise, self.spec.gyro_noise
        # Centripetal acceleration v*w points to the left (+y) when turning left.
        accel = Vector3(
            self._linear_accel / _G + g(0, an),
            self.linear * self.angular / _G + g(0, an),
            1.0 + g(0, an),
        )
        gyro = Vector3(g(0, gn), g(0, gn), math.degrees(self.angular) + g(0, gn))
        mag = Vector3(
            round(300 * math.cos(self.heading)), round(-300 * math.sin(self.heading)), -420.0
        )
        return ImuSample(accel, gyro, mag)


def _clamp(x: float, limit: float) -> float:
    return max(-limit, min(limit, x))
