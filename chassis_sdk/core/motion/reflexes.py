"""A device's reflexes at work: the `Reflexes` rules fed from the read path, acted on
through the motion core, each as an event.

Every observation is checked where it arrives (the telemetry frame's callback), so a
``stop`` writes its zero before the frame's callback returns: the reaction is the read
path's, not a task's wake-up. What each action does:

* ``stop``: the command in force ends at once (a zero is written) and every source
  must give a new command (a streaming one a neutral first), as after an e-stop. While
  a tilt, a critical battery or a degraded link lasts, motion stays blocked
  (``REFLEX_TILT``...); a stall and a geofence block only at their start, so the robot
  can be driven clear. A bumper's block is the device's own latch (``FRONT_BUMPER``).
* ``back_off``: after a bumper hit, the latch is cleared and the robot drives
  ``distance`` away from it at ``speed``, as the highest source (``"reflex"``), then
  stops; a goal or a command in force was ended by the hit.
* ``slow``: every command is capped at ``speed`` while the hazard lasts.
* ``ignore``: only the event.
"""

from __future__ import annotations

import contextlib
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Final

import anyio

from ...errors import ChassisError
from ..alarm import LOOP_STALL, Alarm
from ..events import EventKind, Measure, RobotEvent
from .safety import Reflexes, SafetyPolicy, Trigger

if TYPE_CHECKING:
    from ..odometry import Odometry
    from .drive import Motion
    from .goals import Goals

__all__ = ["BACK_OFF_TIMEOUT", "REFLEX_PRIORITY", "ReflexRunner", "back_off_on"]

#: The reflexes' source priority: above every other kind.
REFLEX_PRIORITY: Final = 1000
#: The longest a back-off drives (s).
BACK_OFF_TIMEOUT: Final = 5.0
#: Hazards whose ``stop`` blocks only at its start (the robot must be driven clear,
#: or the hazard is only seen while moving); the others block while they last.
_MOMENTARY: Final = frozenset({"stall", "geofence", "link"})
#: How long a back-off waits for the cleared latch to show in telemetry (s).
RELEASE_WAIT: Final = 1.0


class ReflexRunner:
    """The reflexes of one device.

    Args:
        motion: The device's motion core.
        policy: The `SafetyPolicy`.
        emit: Publishes an event (``REFLEX``, ``REFLEX_ENDED``, ``SAFETY_OVERRIDDEN``).
        back_off: Clears the bumper latch (``"front"`` or ``"rear"``) and drives the
            distance away at the speed, or ``None`` (a device without bumpers); run by
            `run`, the device's background task when the policy backs off.
        pose: The odometry pose now (for the geofence).
        acting: False for a read-only device (a viewer): no reflex, no event (it
            could not stop the robot, so it says nothing it did not do).
        logger: Where reflexes are logged.
    """

    def __init__(
        self,
        motion: Motion,
        policy: SafetyPolicy,
        emit: Callable[[RobotEvent], None],
        *,
        back_off: Callable[[str, float, float, int], Awaitable[None]] | None = None,
        pose: Callable[[], Odometry | None] = lambda: None,
        acting: bool = True,
        logger: logging.Logger,
    ) -> None:
        self.rules = Reflexes(policy)
        self.policy = policy
        self._motion = motion
        self._emit = emit
        self._back_off = back_off
        self._pose_of = pose
        #: Whether reflexes act (False on a read-only device).
        self.acting = acting
        self._fence = policy.fence is not None
        self._model_critical = False
        self._measured = 0.0  # the last measured linear speed (m/s)
        self._link_command: object = None
        self._link_since = 0.0
        self._announced = False
        self._backing: deque[tuple[Trigger, int]] = deque(maxlen=2)
        self._wake = Alarm()
        self._log = logger
        motion.priorities.setdefault("reflex", REFLEX_PRIORITY)
        #: Reflexes acted on since the start, by hazard.
        self.count: dict[str, int] = {}
        #: The last reflex, as its event, or ``None``.
        self.last: RobotEvent | None = None

    def announce(self, now: float) -> None:
        """Say, once (at the first connection), which hazards the policy ignores."""
        ignored = self.policy.ignored
        if ignored and self.acting and not self._announced:
            self._announced = True
            self._log.warning("safety: ignoring %s (allow_unsafe)", ", ".join(ignored))
            for hazard in ignored:
                self._emit(RobotEvent(EventKind.SAFETY_OVERRIDDEN, hazard, now, action="ignore"))

    # --- observations (from the read path) ---------------------------------------------------

    def bumpers(self, front: bool, rear: bool, now: float) -> None:
        self._act(self.rules.bumpers(front, rear, now))

    def moved(self, measured: float, now: float) -> None:
        """A velocity sample (m/s): the stall watch while a command is in force, and
        the geofence."""
        self._measured = measured
        watchdog = self._motion.watchdog
        rules = self.rules
        active = watchdog.active
        if active is not None or rules.stalling:
            commanded = 0.0
            if active is not None:
                written = watchdog.written  # wheel mode: (left, right), their mean
                commanded = written[0] if active.axes != "wheels" else sum(written) / 2
            self._act(rules.speeds(commanded, measured, now))
        if self._fence:
            odometry = self._pose_of()
            if odometry is not None:
                self._act(rules.pose(odometry.x, odometry.y, now))

    def imu(self, ax: float, ay: float, az: float, now: float) -> None:
        self._act(self.rules.imu(ax, ay, az, now))

    @property
    def watches_voltage(self) -> bool:
        """Whether battery readings are wanted (a critical voltage is set)."""
        return self.policy.battery_critical is not None

    def voltage(self, volts: float, now: float) -> None:
        self._act(self.rules.voltage(volts, now, self._model_critical))

    def battery_level(self, critical: bool, volts: float, now: float) -> None:
        """The battery model's ``BATTERY_CRITICAL`` (True) or ``BATTERY_OK`` (False)."""
        self._model_critical = critical
        self._act(self.rules.voltage(volts, now, critical))

    def link(self, silence: float | None, now: float, late: float = 0.0) -> bool:
        """At a resend (``late`` s after it was due): False if the link's reflex
        stopped the command. A resend later than `LOOP_STALL` is not judged: the host's
        own loop was held up, so the frames that came meanwhile are not read yet (the
        next resend judges)."""
        if late > LOOP_STALL:
            return True
        active = self._motion.watchdog.active
        if active is not self._link_command:  # a new command: watched afresh
            self._link_command = active
            self._link_since = now
            self.rules.rearm("link")
        if silence is not None:  # silence while moving: not before this command began
            silence = min(silence, now - self._link_since)
        moving = active is not None
        self._act(self.rules.link(silence, moving, now))
        return self._motion.watchdog.active is not None or not moving

    # --- acting ------------------------------------------------------------------------------

    def _act(self, triggers: list[Trigger]) -> None:
        if not self.acting or not triggers:
            return
        try:
            for trigger in triggers:
                if trigger.began:
                    self._began(trigger)
                else:
                    self._ended(trigger)
        except Exception:  # the read path must go on; the block (if any) is in place
            self._log.exception("reflex: acting on %s failed", triggers)

    def _began(self, t: Trigger) -> None:
        self.count[t.hazard] = self.count.get(t.hazard, 0) + 1
        action = t.reflex.action
        motion = self._motion
        origin = f"reflex {t.hazard}"
        if action == "stop" and t.hazard != "bumper":
            motion.set_blocks(origin, [t.block])
            if t.hazard in _MOMENTARY:
                motion.set_blocks(origin, [])  # ended the command; drive it clear
        elif action == "slow":
            motion.set_cap(origin, t.reflex.speed)
        elif action == "back_off":
            # Only from a bumper it was driving towards, and not after a stop since.
            towards = self._measured > 0.02 if t.source == "front" else self._measured < -0.02
            if towards:
                self._backing.append((t, motion.arbiter.epoch))
                self._wake.wake()
        what = ", ".join(f"{k} {v:.3g}" for k, v in t.values)
        self._log.warning(
            "reflex: %s%s -> %s%s",
            t.hazard,
            f" {t.source}" if t.source else "",
            action,
            f" ({what})" if what else "",
        )
        values = tuple(Measure(k, v) for k, v in t.values)
        event = RobotEvent(EventKind.REFLEX, _name(t), t.timestamp, action=action, values=values)
        self.last = event
        self._emit(event)

    def clear(self) -> None:
        """Re-arm the reflexes that act once (stall, geofence, link): each triggers
        again when next seen. A tilt or a critical battery blocks for as long as it
        lasts, whatever is cleared."""
        for hazard in _MOMENTARY:
            self.rules.rearm(hazard)

    @property
    def needs_task(self) -> bool:
        """Whether `run` must run (the policy backs off from a bumper)."""
        return self.policy.bumper.action == "back_off" and self._back_off is not None

    async def run(self) -> None:
        """The back-offs, one at a time, until cancelled (a background task)."""
        while True:
            while not self._backing:
                await self._wake.sleep(None)
            t, epoch = self._backing.popleft()
            if self._back_off is None:
                continue
            try:
                await self._back_off(t.source, t.reflex.distance, t.reflex.speed, epoch)
            except Exception:  # a failed back-off leaves the robot stopped, the device up
                self._log.exception("reflex: the back-off from the %s bumper failed", t.source)

    def _ended(self, t: Trigger) -> None:
        action = t.reflex.action
        lasting = action == "slow" or (
            action == "stop" and t.hazard not in _MOMENTARY and t.hazard != "bumper"
        )
        if not lasting:
            return  # nothing of it holds (the bumper's own edge says it cleared)
        motion = self._motion
        origin = f"reflex {t.hazard}"
        motion.set_blocks(origin, [])
        motion.set_cap(origin, None)
        self._emit(
            RobotEvent(EventKind.REFLEX_ENDED, _name(t), t.timestamp, action=t.reflex.action)
        )


def _name(t: Trigger) -> str:
    return f"{t.source}_{t.hazard}" if t.source else t.hazard


async def back_off_on(
    motion: Motion,
    goals: Goals,
    side: str,
    distance: float,
    speed: float,
    release: Callable[[str], Awaitable[None]],
    epoch: int,
) -> None:
    """Clear ``side``'s bumper latch (``release``), then drive ``distance`` away from it
    at ``speed``, closed on odometry, as the ``"reflex"`` source; then stop. Nothing is
    done if a stop (or another block) came since the hit (``epoch``: the arbiter's
    then); if the latch does not clear (still pressed) or something else blocks, it
    stays stopped."""
    if motion.arbiter.epoch != epoch:
        return
    await release(side)
    with anyio.move_on_after(RELEASE_WAIT):  # the next telemetry frame shows the latch gone
        while motion.blocks:
            await motion.blocks_changed.sleep(None)
    if motion.arbiter.epoch != epoch:
        return  # a stop came meanwhile
    with contextlib.suppress(ChassisError):  # still blocked, or ended: it stays stopped
        await goals.drive_distance(
            -distance if side == "front" else distance, speed, None, BACK_OFF_TIMEOUT, kind="reflex"
        )
