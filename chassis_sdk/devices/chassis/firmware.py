"""A sans-IO model of the protocol A chassis firmware.

The simulator that serves it is `chassis_sdk.sim.ChassisSimulator`.

The model behaves like the device as far as a host can tell: 0x81 telemetry at 50 Hz
(switchable), 0xB1 at 20 Hz when enabled, replies to every read request, skid-steer
kinematics with an acceleration ramp, the software e-stop, the docking state machine,
a battery that sags under load (or, with ``ChassisSpec.pack``, a pack model: a charge
the wheels' currents drain, a chemistry's voltage curve and an internal resistance),
bumpers and driver faults that tests can trigger and 0x05 clears, and the firmware's own
command timeout: the wheels stop if no 0x02 arrives for 0.5 s, which is why the SDK's
watchdog exists.

It can be miscalibrated as a real base is (``ChassisSpec.wheel_diameter_error``,
``ChassisSpec.turn_slip``, and a random slip, ``ChassisSpec.slip_noise``): the
telemetry reports what the encoders count, the true pose (`ChassisFirmware.true_pose`,
`ChassisFirmware.odometer`) is where the robot really went, for tests to hold a
calibration or a goal's accuracy against.

With a world (``ChassisFirmware(world=...)``, a `chassis_sdk.sim.World` or anything
that has its ``sweep``), the robot is a box (``ChassisSpec.footprint``) that stops at
the walls: running into one latches the bumper of the end that hit it and stops the
wheels at once. ``stall_wheels`` holds the wheels still for a while (commanded, not
turning), as a jammed drive would.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Literal

from ...core.firmware import FirmwareModel, Obstacles, check_fits, check_motion, next_slot
from ...core.pack import Pack, PackSpec
from .messages import (
    ChassisInfo,
    ChassisMessage,
    ChassisStatus,
    CommandId,
    DockingState,
    DriverError,
    DriverStatus,
    DriveVelocity,
    DriveWheels,
    FaultClear,
    FirmwareVersion,
    HardwareVersion,
    HostCommand,
    MotorStatus,
    PowerTelemetry,
    ShipDate,
    Telemetry,
    WheelCurrents,
    WheelDriver,
    WheelSpeeds,
)
from .protocol import ChassisCommandDecoder, ChassisEncoder

__all__ = ["ChassisFirmware", "ChassisSpec", "Obstacles"]

_WHEELS = ("front_left", "front_right", "rear_left", "rear_right")
_DRIVER_ERROR_BITS = (
    ChassisStatus.FRONT_LEFT_DRIVER_ERROR,
    ChassisStatus.FRONT_RIGHT_DRIVER_ERROR,
    ChassisStatus.REAR_LEFT_DRIVER_ERROR,
    ChassisStatus.REAR_RIGHT_DRIVER_ERROR,
)
#: The docking walk after 0x06 start: each state holds ``docking_step`` seconds.
_DOCKING_WALK = (DockingState.SEARCHING, DockingState.CENTER_FOUND, DockingState.CONTACT)


@dataclass(slots=True)
class ChassisSpec:
    """What the simulated chassis reports and how it moves.

    The geometry is the vendor document's example (725/500/170/30/1000 mm).
    """

    firmware_version: int = 103
    hardware_version: str = "ZKWL-brush-motor-chassis"
    ship_date: tuple[int, int, int] = (2024, 1, 2)
    info: ChassisInfo = field(default_factory=lambda: ChassisInfo(0.725, 0.5, 0.17, 30, 1000))
    telemetry_period: float = 0.02
    power_period: float = 0.05
    command_timeout: float = 0.5
    max_acceleration: float = 1.5  #: m/s² per wheel
    max_wheel_speed: float = 2.0  #: m/s
    #: V, open-circuit: a charged 8S LiFePO4 pack, 3.4 V a cell (``OCV_CURVES``' 100 %),
    #: the pack `PackSpec()` models and the example profile describes. (25.6 V, the
    #: pack's nominal voltage, is 3.2 V a cell at rest: a profile read it as 20 %.)
    battery_full: float = 27.2
    battery_resistance: float = 0.03  #: Ω: sag per ampere drawn
    battery_drain: float = 0.0005  #: V per second of driving
    docking_step: float = 1.0  #: s per docking state
    #: A pack model instead of the linear battery above (``battery_*`` then unused):
    #: its charge drains with the wheels' currents (idle, speed and acceleration), its
    #: voltage follows the chemistry's curve and sags by ``I * R``; ``None``: the
    #: linear battery, as before.
    pack: PackSpec | None = None
    #: How FRAME-NUMS count (the document leaves it open): ``"per-id"``, one counter
    #: per frame id, or ``"shared"``, one counter for every frame the chassis sends.
    sequence: Literal["per-id", "shared"] = "per-id"
    #: The true wheels' diameter over the one the firmware believes, minus 1 (0.04:
    #: 4 % bigger): the robot goes ``1 + wheel_diameter_error`` times as far (and
    #: turns as much more) as its encoders report.
    wheel_diameter_error: float = 0.0
    #: Skid slip in turns: the robot turns ``1 - turn_slip`` times what the wheels'
    #: speed difference over the track says (0.2: 20 % less).
    turn_slip: float = 0.0
    #: Random slip: each physics step the true motion (forward and turning, each on its
    #: own) is ``1 + N(0, slip_noise)`` times what the wheels say (0.01: 1 %); 0: none.
    slip_noise: float = 0.0
    #: Seed of the random slip, for repeatable runs.
    seed: int = 0
    #: The robot's box in a world, ``(length, width)`` in metres; ``None``: the
    #: wheelbase plus a wheel's diameter long, the track width wide.
    footprint: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        check_motion(self.wheel_diameter_error, self.turn_slip, self.slip_noise, self.footprint)


#: The status bit of each level ``ChassisFirmware.status`` lists, in its order.
_STATUS_BITS = (
    ChassisStatus.HARDWARE_ESTOP,
    ChassisStatus.SOFTWARE_ESTOP,
    ChassisStatus.REMOTE_ESTOP,
    ChassisStatus.REMOTE_OFFLINE,
    ChassisStatus.FRONT_DRIVER_OFFLINE,
    ChassisStatus.REAR_DRIVER_OFFLINE,
    *_DRIVER_ERROR_BITS,
    ChassisStatus.FRONT_BUMPER,
    ChassisStatus.REAR_BUMPER,
    ChassisStatus.DOCKING_ENABLED,
)


def _advance(
    pose: tuple[float, float, float],
    wheels: list[float],
    spec: ChassisSpec,
    dt: float,
    slip: tuple[float, float] = (1.0, 1.0),
) -> tuple[float, float, float]:
    """The true pose after ``dt`` at these (encoder) wheel speeds (midpoint rule), with
    the spec's miscalibration and this step's random ``slip`` (forward, turning
    factors), for tests to hold odometry against."""
    left, right = (wheels[0] + wheels[2]) / 2, (wheels[1] + wheels[3]) / 2
    true = 1.0 + spec.wheel_diameter_error
    v = (left + right) / 2 * true * slip[0]
    w = (right - left) / spec.info.track_width * true * (1.0 - spec.turn_slip) * slip[1]
    x, y, heading = pose
    mid = heading + w * dt / 2
    return (x + v * dt * math.cos(mid), y + v * dt * math.sin(mid), heading + w * dt)


def _slip(rng: random.Random, sigma: float, wheels: list[float]) -> tuple[float, float]:
    """A step's random slip factors (forward, turning), or none (``sigma`` 0 or the
    wheels still: then nothing is drawn)."""
    if not sigma or not any(wheels):
        return (1.0, 1.0)
    return (1.0 + rng.gauss(0.0, sigma), 1.0 + rng.gauss(0.0, sigma))


class ChassisFirmware(FirmwareModel[HostCommand]):
    """The firmware model: ``receive(bytes, now)`` and ``poll(now)`` return bytes to send.

    Tests and the CLI reach into it to trigger faults: `press_bumper`,
    `set_driver_fault`, `set_driver_offline`, `set_hardware_estop`,
    `set_remote_estop`, `set_battery`, `stall_wheels`, `reset`; `hold_bumper` and
    `ignored` make it refuse what the host asks (for tests of confirmation).

    Args:
        spec: Device parameters (versions, geometry, rates, miscalibration).
        world: Walls to run into (see `world`); ``None``: open space.

    Raises:
        ValueError: The robot at the origin touches a wall of ``world``.
    """

    def __init__(self, spec: ChassisSpec | None = None, *, world: Obstacles | None = None) -> None:
        super().__init__()
        self.spec = spec or ChassisSpec()
        self._slip_rng = random.Random(self.spec.seed)
        #: Collisions with the world's walls so far (each latched a bumper).
        self.impacts = 0
        self._stalled_until = -math.inf  # a jammed drive is physical: a reset keeps it
        self._held = False  # stalled at the latest physics step
        self.hardware_estop = False
        self.remote_estop = False
        self.remote_online = False
        self.drivers_offline = [False, False]
        #: Bumpers physically held pressed (front, rear): 0x05 cannot clear them.
        self.bumpers_held = [False, False]
        #: Commands this firmware receives and drops unexecuted (a chassis that does not
        #: confirm: its telemetry never shows the effect).
        self.ignored: set[CommandId] = set()
        self._battery_open = self.spec.battery_full  # the battery outlives a reset
        #: The pack model (``spec.pack``), or ``None``; its ``charge`` is the truth.
        self.pack = None if self.spec.pack is None else Pack(self.spec.pack)
        #: The true pose (x m, y m, heading rad unwrapped) from the simulated wheels
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
        check_fits("the chassis", world, self.pose, self.footprint)
        self._world = world

    @property
    def footprint(self) -> tuple[float, float]:
        """The robot's box, ``(length, width)`` in metres (``ChassisSpec.footprint``)."""
        if self.spec.footprint is not None:
            return self.spec.footprint
        info = self.spec.info
        return (info.wheelbase + info.wheel_diameter, info.track_width)

    @property
    def true_pose(self) -> tuple[float, float, float]:
        """Where the robot truly is: x, y (m) and heading (rad, unwrapped) from its
        start pose, with the wheels' miscalibration and slip, stopped by walls. The
        telemetry (and the host's odometry) reports what the encoders count instead."""
        return self.pose

    def _power_on(self) -> None:
        """The state after power-up (the hardware e-stop button is physical: it stays)."""
        self._decoder = ChassisCommandDecoder()
        self._encoders: dict[type, ChassisEncoder] = {}  # sequence numbers from 0
        self.telemetry_enabled = True
        self.power_enabled = False
        self.software_estop = False
        self.front_bumper = False
        self.rear_bumper = False
        self.driver_errors = [DriverError(0)] * 4
        self.docking_enabled = False
        self.docking_state = DockingState.SEARCHING
        self._docking_since = 0.0
        self.target = [0.0, 0.0, 0.0, 0.0]  # wheel speed targets, m/s (FL, FR, RL, RR)
        self.wheels = [0.0, 0.0, 0.0, 0.0]
        self._accel = [0.0, 0.0, 0.0, 0.0]
        self._peak = [0.0, 0.0, 0.0, 0.0]
        self._last_drive = -math.inf
        self._last_step: float | None = None
        self._next_telemetry = 0.0
        self._next_power = 0.0

    # --- fault injection ------------------------------------------------------------------

    def press_bumper(self, front: bool = True) -> None:
        """Trigger (latch) a bumper: the wheels stop until 0x05 clears it."""
        if front:
            self.front_bumper = True
        else:
            self.rear_bumper = True

    def set_driver_fault(self, wheel: int, errors: DriverError) -> None:
        """Latch driver error bits on wheel 0..3 (FL, FR, RL, RR); 0x05 clears them."""
        self.driver_errors[wheel] = DriverError(errors)

    def set_hardware_estop(self, pressed: bool) -> None:
        """Press or release the hardware emergency-stop button."""
        self.hardware_estop = pressed

    def set_remote_estop(self, pressed: bool) -> None:
        """Press or release the remote control's emergency stop (the remote comes
        online for it)."""
        self.remote_estop = pressed
        self.remote_online = True

    def hold_bumper(self, front: bool = True, held: bool = True) -> None:
        """Hold a bumper pressed (it latches, and 0x05 cannot clear it while held), or
        let it go (the latch stays until 0x05)."""
        self.bumpers_held[0 if front else 1] = held
        if held:
            self.press_bumper(front)

    def release_bumper(self, front: bool = True) -> None:
        """Let a bumper go and clear its latch, as if it had never been pressed (the
        simulator operator's undo; the host's way is 0x05)."""
        self.bumpers_held[0 if front else 1] = False
        if front:
            self.front_bumper = False
        else:
            self.rear_bumper = False

    def set_driver_offline(self, front: bool, offline: bool = True) -> None:
        """Take the front or rear motor-driver board off the bus (or put it back)."""
        self.drivers_offline[0 if front else 1] = offline

    def set_battery(self, voltage: float) -> None:
        """Set the battery's open-circuit voltage (it keeps draining from there); with a
        pack model, its charge becomes the one this voltage shows."""
        self._battery_open = voltage
        if self.pack is not None:
            self.pack.set_open_voltage(voltage)

    def stall_wheels(self, now: float, seconds: float) -> None:
        """Hold the wheels still from ``now`` for ``seconds`` (0 ends a stall): they are
        commanded but do not turn (the telemetry's speeds are 0, the motors draw their
        stall current), as a jammed drive or a wheel against a kerb would. No status
        bit says so; a reset does not end it."""
        self._stalled_until = now + max(0.0, seconds)

    def stalled(self, now: float) -> bool:
        """True while `stall_wheels` holds the wheels at ``now``."""
        return now < self._stalled_until

    # --- sans-IO interface --------------------------------------------------------------------

    def on_connect(self, now: float) -> None:
        """Start the clocks (called when the simulator starts or a client connects)."""
        self._last_step = now
        self._next_telemetry = now
        self._next_power = now

    def poll(self, now: float) -> bytes:
        """Advance the model to ``now``; return the periodic frames that fell due."""
        if self.booting(now):
            return b""
        self._step(now)
        out = bytearray()
        if self.telemetry_enabled and now >= self._next_telemetry:
            out += self._encode(self.telemetry())
            self._next_telemetry = next_slot(self._next_telemetry, self.spec.telemetry_period, now)
        if self.power_enabled and now >= self._next_power:
            out += self._encode(self.power())
            self._next_power = next_slot(self._next_power, self.spec.power_period, now)
        return bytes(out)

    def next_deadline(self) -> float:
        """When `poll` next has a frame to send (or the physics a step to take)."""
        due = [self._next_telemetry if self.telemetry_enabled else math.inf]
        if self.power_enabled:
            due.append(self._next_power)
        step = (self._last_step or 0.0) + 0.02
        return min(*due, step)

    # --- commands ---------------------------------------------------------------------------------

    def _execute(self, cmd: HostCommand, now: float) -> bytes:
        if isinstance(cmd, DriveVelocity | DriveWheels):
            self._drive(cmd, now)
            return b""
        cid, value = cmd.id, cmd.value
        if cid in self.ignored:
            return b""
        if cid is CommandId.TELEMETRY:
            self.telemetry_enabled = bool(value)
            if self.telemetry_enabled:
                self._next_telemetry = now
        elif cid is CommandId.POWER_TELEMETRY:
            self.power_enabled = bool(value)
            if self.power_enabled:
                self._next_power = now
        elif cid is CommandId.EMERGENCY_STOP:
            self.software_estop = bool(value)
        elif cid is CommandId.CLEAR_FAULTS:
            what = FaultClear(value & 0x7)
            if FaultClear.DRIVER in what:
                self.driver_errors = [DriverError(0)] * 4
            if FaultClear.FRONT_BUMPER in what and not self.bumpers_held[0]:
                self.front_bumper = False
            if FaultClear.REAR_BUMPER in what and not self.bumpers_held[1]:
                self.rear_bumper = False
        elif cid is CommandId.DOCKING:
            if value:
                self.docking_enabled = True
                self.docking_state = DockingState.SEARCHING
                self._docking_since = now
            elif self.docking_enabled:
                self.docking_enabled = False
                self.docking_state = DockingState.EXITED
        elif cid is CommandId.FIRMWARE_VERSION:
            return self._encode(FirmwareVersion(self.spec.firmware_version))
        elif cid is CommandId.HARDWARE_VERSION:
            return self._encode(HardwareVersion(self.spec.hardware_version))
        elif cid is CommandId.CHASSIS_INFO:
            return self._encode(self.spec.info)
        elif cid is CommandId.SHIP_DATE:
            return self._encode(ShipDate(*self.spec.ship_date))
        elif cid is CommandId.DRIVER_STATUS:
            return self._encode(self.driver_status())
        return b""

    def _encode(self, msg: ChassisMessage) -> bytes:
        """A frame numbered as ``spec.sequence`` says (each message type is one id)."""
        key = object if self.spec.sequence == "shared" else type(msg)
        encoder = self._encoders.get(key)
        if encoder is None:
            encoder = self._encoders[key] = ChassisEncoder()
        return encoder.encode(msg)

    def _drive(self, cmd: DriveVelocity | DriveWheels, now: float) -> None:
        self._last_drive = now
        if isinstance(cmd, DriveVelocity):
            v = cmd.linear_mm / 1000
            half = cmd.angular * self.spec.info.track_width / 2
            left, right = v - half, v + half
        else:
            left, right = cmd.left_mm / 1000, cmd.right_mm / 1000
        cap = self.spec.max_wheel_speed
        left = max(-cap, min(cap, left))
        right = max(-cap, min(cap, right))
        self.target = [left, right, left, right]

    # --- physics ----------------------------------------------------------------------------------

    @property
    def status(self) -> ChassisStatus:
        """The status bits as the next telemetry frame will report them."""
        levels = (
            self.hardware_estop,
            self.software_estop,
            self.remote_estop,
            not self.remote_online,
            *self.drivers_offline,
            *(bool(err) for err in self.driver_errors),
            self.front_bumper,
            self.rear_bumper,
            self.docking_enabled,
        )
        bits = 0
        for bit, level in zip(_STATUS_BITS, levels, strict=True):
            if level:
                bits |= bit
        return ChassisStatus(bits)

    def _may_move(self, now: float) -> bool:
        return (
            now - self._last_drive <= self.spec.command_timeout
            and not (self.software_estop or self.hardware_estop or self.remote_estop)
            and not any(self.drivers_offline)
            and not (self.front_bumper or self.rear_bumper)
            and not any(self.driver_errors)
        )

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
        may_move = self._may_move(now)
        if not may_move:
            self.target = [0.0, 0.0, 0.0, 0.0]
        max_accel = self.spec.max_acceleration
        max_dv = max_accel * dt
        stalled = self._held = self.stalled(now)
        for i in range(4):
            goal = self.target[i] if may_move else 0.0
            dv = max(-max_dv, min(max_dv, goal - self.wheels[i]))
            if not may_move and (self.software_estop or self.hardware_estop or self.remote_estop):
                dv = goal - self.wheels[i]  # an emergency stop brakes at once
            if stalled:
                dv = -self.wheels[i]  # held: the wheels do not turn whatever is asked
            self.wheels[i] += dv
            # The current follows what the motor drives, at most the rated acceleration:
            # an emergency stop's instant halt is the brake's, and dividing it by a step
            # microseconds long drew thousands of amperes and a negative voltage.
            self._accel[i] = 0.0 if stalled else max(-max_accel, min(max_accel, dv / dt))
            self._peak[i] = max(self._peak[i], abs(self._current(i)))
        start = self.pose
        slip = _slip(self._slip_rng, self.spec.slip_noise, self.wheels)
        end = _advance(start, self.wheels, self.spec, elapsed, slip)
        if self._world is not None and end != start:
            end, touch = self._world.sweep(start, end, *self.footprint)
            if touch is not None:
                self._hit(touch)
        self.pose = end
        self.odometer += math.hypot(end[0] - start[0], end[1] - start[1])
        if self.pack is not None:
            self.pack.draw(self._total_current(), dt)
        elif any(abs(w) > 1e-6 for w in self.wheels):
            self._battery_open -= self.spec.battery_drain * dt
        if self.docking_enabled:
            step = int((now - self._docking_since) / self.spec.docking_step)
            walk = _DOCKING_WALK
            self.docking_state = walk[step] if step < len(walk) else DockingState.DOCKED

    def _hit(self, touch: tuple[float, float]) -> None:
        """The robot ran into a wall: the bumper of the end that leads (or, turning on
        the spot, of the end that touched) latches, and the wheels stop at once."""
        linear = sum(self.wheels) / 4
        front = linear > 0 if abs(linear) > 1e-9 else touch[0] >= 0
        self.press_bumper(front)
        self.impacts += 1
        self.wheels = [0.0, 0.0, 0.0, 0.0]
        self._accel = [0.0, 0.0, 0.0, 0.0]

    def _current(self, i: int) -> float:
        # A stalled motor draws its stall current, growing with what it is asked for.
        stall = 6.0 * abs(self.target[i]) if self._held else 0.0
        return 0.3 + 3.0 * abs(self.wheels[i]) + 4.0 * abs(self._accel[i]) + stall

    def _total_current(self) -> float:
        return sum(self._current(i) for i in range(4))

    @property
    def battery_voltage(self) -> float:
        """Terminal voltage: open-circuit voltage minus the sag under the current drawn
        (never below zero: a battery set or drained that far reads empty)."""
        total = self._total_current()
        if self.pack is not None:
            return self.pack.terminal_voltage(total)
        return max(0.0, self._battery_open - self.spec.battery_resistance * total)

    @property
    def battery_charge(self) -> float | None:
        """The pack model's true state of charge (percent), or ``None`` without one."""
        return None if self.pack is None else self.pack.charge

    def telemetry(self) -> Telemetry:
        """The telemetry frame the model would send now."""
        fl, fr, rl, rr = self.wheels
        track = self.spec.info.track_width
        left, right = (fl + rl) / 2, (fr + rr) / 2
        return Telemetry(
            voltage=round(self.battery_voltage, 1),
            status=self.status,
            docking=self.docking_state,
            linear=(left + right) / 2,
            angular=(right - left) / track,
            wheels=WheelSpeeds(fl, fr, rl, rr),
        )

    def power(self) -> PowerTelemetry:
        """The 0xB1 frame the model would send now."""
        v = self.battery_voltage
        return PowerTelemetry(WheelCurrents(*(self._current(i) for i in range(4))), v, v)

    def driver_status(self) -> DriverStatus:
        """The 0xB0 reply the model would send now."""
        drivers = []
        for i in range(4):
            motor = MotorStatus.SERVO_STARTED
            if abs(self.wheels[i]) < 1e-3:
                motor |= MotorStatus.ZERO_SPEED
            else:
                motor |= MotorStatus.SERVO_RUNNING
            if abs(self.wheels[i] - self.target[i]) < 1e-3:
                motor |= MotorStatus.TARGET_SPEED_REACHED
            if self.driver_errors[i]:
                motor |= MotorStatus.ERROR_WARNING
            sign = 1.0 if self.wheels[i] >= 0 else -1.0
            drivers.append(
                WheelDriver(self.driver_errors[i], motor, sign * self._current(i), self._peak[i])
            )
        v = self.battery_voltage
        fl, fr, rl, rr = drivers
        return DriverStatus(fl, fr, rl, rr, 35.5, 34.0, v, v)
