"""What the ROS 2 bridge takes in: ``cmd_vel`` (``Twist``, or ``TwistStamped``) and
``emergency_stop`` (``Bool``), each sample checked (finite, fresh by its stamp, within
the limits) and given to the device's motion core through its writer's source (kind
``"ros2"``, streaming: one per DDS writer, told apart by the sample's publication
handle), or to its e-stop. Refusals go to the bridge's reporter."""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable
from typing import Any

import anyio
import anyio.lowlevel

from ...core.device import Device
from ...core.motion import MotionSource
from ...errors import ChassisError
from ...recording.ros2_types import TOPICS
from ..inbound import CommandError, check_fresh
from .dds import Reader

__all__ = ["Inbound"]

#: Seconds a writer that does not drive may be silent before its source is forgotten.
_IDLE = 5.0

_log = logging.getLogger("chassis_sdk.integrations.ros2")


class Inbound:
    """``cmd_vel`` and ``emergency_stop`` in, for one device (see the module docstring).

    Args:
        device: The device.
        namespace: The bridge's namespace (for the topics' names).
        stamped: ``cmd_vel`` is ``TwistStamped``: a sample's age is its stamp's.
        command_timeout: How long one sample holds (s), from its stamp.
        max_linear, max_angular: Clamps (``None``: the device's range).
        refuse: Reports one refusal: ``refuse(topic, why)``.
    """

    def __init__(
        self,
        device: Device[Any, Any],
        namespace: str,
        *,
        stamped: bool,
        command_timeout: float,
        max_linear: float | None,
        max_angular: float | None,
        refuse: Callable[[str, str], None],
    ) -> None:
        self.device = device
        self.namespace = namespace
        self.stamped = stamped
        self.command_timeout = command_timeout
        self.max_linear = max_linear
        self.max_angular = max_angular
        self._refuse = refuse
        #: ``cmd_vel`` samples taken by the motion core.
        self.commands = 0
        #: Stops because the last ``cmd_vel`` writer went away.
        self.writer_gone_stops = 0
        self._stop_now = False
        # Each cmd_vel writer's source, by its DDS publication handle, and when it was
        # last heard from.
        self._sources: dict[int, MotionSource] = {}
        self._heard: dict[int, float] = {}
        self._writers_seen = 0
        # A device without an e-stop of its own: the e-stop topic blocks motion in the
        # core while engaged (this bridge's block, cleared when it ends).
        self._estop_block = False

    def end(self) -> None:
        """The bridge ends: the block its e-stop topic set (on a device without an
        e-stop) is lifted."""
        if self._estop_block:
            self._estop_block = False
            self.device.motion.set_blocks(self._block_origin, ())

    def writer_gone(self) -> None:
        """The last ``cmd_vel`` writer left (on the loop, from the reader's listener,
        which then wakes the command loop)."""
        self._stop_now = True

    def _velocity_of(self, sample: Any) -> tuple[float, float, float]:
        """``(linear, angular, age)`` of a sample: its age (s) from its stamp, 0 if none."""
        twist = sample.twist if self.stamped else sample
        age = 0.0
        if self.stamped:
            stamp = sample.header.stamp
            if stamp.sec or stamp.nanosec:  # an unset stamp is no stamp
                age = check_fresh(stamp.sec + stamp.nanosec * 1e-9, self.command_timeout)
        linear, angular = float(twist.linear.x), float(twist.angular.z)
        if not (math.isfinite(linear) and math.isfinite(angular)):
            raise CommandError(f"linear.x and angular.z must be finite, got {linear}, {angular}")
        if self.max_linear is not None:
            linear = max(-self.max_linear, min(self.max_linear, linear))
        if self.max_angular is not None:
            angular = max(-self.max_angular, min(self.max_angular, angular))
        return linear, angular, max(0.0, age)  # a stamp just ahead (within the skew): now

    async def commands_from(self, reader: Reader[Any]) -> None:
        """Act on ``cmd_vel``: each valid sample to the motion core through its writer's
        source (the core arbitrates between writers, paces the writes and keeps the
        newest); a stop at once when the last writer leaves, if one was driving (the
        reader wakes this loop for both)."""
        where = TOPICS["cmd_vel"].qualified(self.namespace)
        try:
            while True:
                await reader.wait()
                await anyio.lowlevel.checkpoint()  # a flood of refusals still lets others run
                for sample in reader.take():
                    self._command(where, self._source_of(where, sample), sample)
                if self._stop_now:
                    self._stop_now = False
                    if self._close_sources():
                        self.writer_gone_stops += 1
                        _log.info("%s: no writer left; the robot is stopped", where)
        finally:
            self._close_sources()  # the bridge ending: the robot stops if one was driving

    def _source_of(self, where: str, sample: Any) -> MotionSource:
        """The source of the writer that wrote ``sample`` (DDS's publication handle): each
        ``cmd_vel`` writer (Nav2, a teleop node) is a client of its own in the core."""
        info = getattr(sample, "sample_info", None)
        handle = int(getattr(info, "publication_handle", 0) or 0)
        source = self._sources.get(handle)
        if source is None:
            self._forget_idle()
            self._writers_seen += 1
            source = self.device.motion.source(
                f"ros2 {where} writer {self._writers_seen}", kind="ros2", streaming=True
            )
            self._sources[handle] = source
        self._heard[handle] = time.monotonic()
        return source

    def _forget_idle(self) -> None:
        """Close the sources of writers silent for `_IDLE` s that do not drive (a writer
        that left while others stay): memory stays bounded however many come and go."""
        now = time.monotonic()
        for handle, heard in list(self._heard.items()):
            source = self._sources[handle]
            if now - heard > _IDLE and not source.driving:
                source.close()
                del self._sources[handle], self._heard[handle]

    def _close_sources(self) -> bool:
        """Close every writer's source; True if one was driving (the robot is stopped)."""
        driving = False
        for source in self._sources.values():
            driving |= source.driving
            with contextlib.suppress(ChassisError):
                source.close()
        self._sources.clear()
        self._heard.clear()
        return driving

    def _command(self, where: str, source: MotionSource, sample: Any) -> None:
        """One sample: refused (counted, reported) or offered to the core."""
        try:
            linear, angular, age = self._velocity_of(sample)
            # Held for command_timeout from its stamp (diff_drive_controller's
            # cmd_vel_timeout): a sample 0.2 s old holds 0.2 s less.
            refusal = source.set_velocity(linear, angular, duration=self.command_timeout, age=age)
        except (CommandError, ValueError) as exc:  # bad, stale, or out of the device's range
            self._refuse(where, str(exc))
            return
        except ChassisError as exc:  # not connected: this command is lost, no more
            self._refuse(where, f"not written: {exc}")
            return
        if refusal is not None:  # blocked (an e-stop), driven by another source, ...
            self._refuse(where, refusal.detail)
            return
        self.commands += 1

    @property
    def _block_origin(self) -> str:
        return f"ros2 {TOPICS['emergency_stop'].qualified(self.namespace)}"

    async def estops_from(self, reader: Reader[Any]) -> None:
        """Act on ``emergency_stop`` at once: the device's e-stop (the core then blocks
        velocity from every source until it is released)."""
        where = TOPICS["emergency_stop"].qualified(self.namespace)
        device: Any = self.device
        while True:
            await reader.wait()
            for sample in reader.take():
                engaged = bool(sample.data)
                try:
                    if not hasattr(device, "emergency_stop"):
                        # No e-stop on the device: the core blocks motion (which ends
                        # the command and writes zero) until the topic releases it.
                        self._estop_block = engaged
                        self.device.motion.set_blocks(
                            self._block_origin, ("SOFTWARE_ESTOP",) if engaged else ()
                        )
                        if engaged:
                            await self.device.stop()
                            raise CommandError(
                                f"a {self.device.device_name} has no e-stop; it was stopped "
                                "and motion is blocked until released"
                            )
                    elif engaged:
                        await device.emergency_stop()
                    else:
                        await device.release_emergency_stop()
                except (CommandError, ChassisError) as exc:
                    self._refuse(where, str(exc))
