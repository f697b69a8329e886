"""The chassis's commands that act on its state, each optionally confirmed by the
telemetry that shows the effect: e-stop, clearing faults, docking, switching streams."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from ...core.device import Device
from ...core.dispatch import Broadcast
from ...errors import RequestTimeoutError
from .messages import ChassisStatus, FaultClear, ReplyId, Telemetry
from .protocol import ChassisEncoder

__all__ = ["ChassisCommands"]

#: How long a release of the software e-stop may take to show in telemetry (s).
_RELEASE_GRACE = 0.5


class ChassisCommands(Device[Any, ReplyId]):
    """E-stop, fault clearing, docking and stream switches of `Chassis`."""

    _encoder: ChassisEncoder
    _telemetry: Broadcast[Telemetry]
    _releasing: float

    async def emergency_stop(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Engage the software emergency stop (0x03) and end any velocity command.

        The chassis reports it in ``Telemetry.status`` (``SOFTWARE_ESTOP``).

        Args:
            confirm: Return only once telemetry shows ``SOFTWARE_ESTOP``.
            timeout: Seconds to wait for that (with ``confirm``).

        Raises:
            RequestTimeoutError: ``confirm`` and the bit did not show in time.
        """
        self._ensure_connected()
        self._releasing = 0.0
        self._motion.set_blocks("software", ("SOFTWARE_ESTOP",))  # ends the command
        self._link.writer.write(self._encoder.emergency_stop(True))
        await self.stop()
        if confirm:
            await self._confirm_bit(ChassisStatus.SOFTWARE_ESTOP, True, timeout)

    async def release_emergency_stop(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Release the software emergency stop (0x03, 0). Nothing moves until a new
        velocity command: the e-stop ended the command that was in force, and a
        streaming source (a dashboard page, a ``cmd_vel`` writer) must send a neutral
        first.

        Args:
            confirm: Return only once telemetry shows ``SOFTWARE_ESTOP`` cleared.
            timeout: Seconds to wait for that (with ``confirm``).
        """
        self._ensure_connected()
        self._motion.set_blocks("software", ())
        # Frames still showing the e-stop (sent before the release took effect) are not
        # a new one for a moment: see Chassis._on_status.
        self._releasing = time.monotonic() + _RELEASE_GRACE
        self._motion.set_blocks(
            "device", tuple(f for f in self.motion_blocked() if f != "SOFTWARE_ESTOP")
        )
        await self._send_confirmed(
            self._encoder.emergency_stop(False),
            ChassisStatus.SOFTWARE_ESTOP,
            False,
            confirm,
            timeout,
        )

    async def clear_faults(
        self,
        *,
        driver: bool = True,
        front_bumper: bool = True,
        rear_bumper: bool = True,
        confirm: bool = False,
        timeout: float = 1.0,
    ) -> None:
        """Clear latched faults (0x05), and forget the reflexes' hazards.

        Args:
            driver: Clear a latched driver fault.
            front_bumper: Clear the front bumper's latch.
            rear_bumper: Clear the rear bumper's latch.
            confirm: Return only once telemetry shows the selected faults clear (a
                bumper still pressed, or a driver still failing, makes this time out).
            timeout: Seconds to wait for that (with ``confirm``).

        Raises:
            ValueError: Nothing selected to clear.
            RequestTimeoutError: ``confirm`` and a selected fault is still set.
        """
        selected = FaultClear(0)
        bits = ChassisStatus(0)
        if driver:
            selected |= FaultClear.DRIVER
            bits |= ChassisStatus.DRIVER_FAULT
        if front_bumper:
            selected |= FaultClear.FRONT_BUMPER
            bits |= ChassisStatus.FRONT_BUMPER
        if rear_bumper:
            selected |= FaultClear.REAR_BUMPER
            bits |= ChassisStatus.REAR_BUMPER
        if not selected:
            raise ValueError("clear_faults() with nothing to clear: select at least one")
        await self._send(self._encoder.clear_faults(selected))
        self.clear_reflexes()
        if confirm:
            await self._confirm(lambda t: not t.status & bits, timeout, f"{bits!r} clear")

    async def start_docking(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Start automatic docking (0x06, 1); follow ``Telemetry.docking``, or
        ``await robot.wait_for(lambda t: t.docking is DockingState.DOCKED, 60)``.

        Args:
            confirm: Return only once telemetry shows ``DOCKING_ENABLED``.
            timeout: Seconds to wait for that (with ``confirm``).
        """
        await self._send_confirmed(
            self._encoder.docking(True), ChassisStatus.DOCKING_ENABLED, True, confirm, timeout
        )

    async def stop_docking(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        """Stop automatic docking (0x06, 0).

        Args:
            confirm: Return only once telemetry shows ``DOCKING_ENABLED`` cleared.
            timeout: Seconds to wait for that (with ``confirm``).
        """
        await self._send_confirmed(
            self._encoder.docking(False), ChassisStatus.DOCKING_ENABLED, False, confirm, timeout
        )

    async def _send_confirmed(
        self, frame: bytes, bit: ChassisStatus, present: bool, confirm: bool, timeout: float
    ) -> None:
        """Send a command; with ``confirm``, wait for telemetry to show ``bit`` as
        ``present`` (set) or not."""
        await self._send(frame)
        if confirm:
            await self._confirm_bit(bit, present, timeout)

    async def _confirm_bit(self, bit: ChassisStatus, present: bool, timeout: float) -> None:
        name = bit.name or repr(bit)
        await self._confirm(
            lambda t: (bit in t.status) is present,
            timeout,
            f"{name} set" if present else f"{name} cleared",
        )

    async def _confirm(
        self, predicate: Callable[[Telemetry], bool], timeout: float, what: str
    ) -> None:
        """Wait for a frame that arrived after the command and shows its effect."""
        sent = time.monotonic()
        try:
            await self.wait_for(lambda t: t.timestamp >= sent and predicate(t), timeout)
        except TimeoutError:
            raise RequestTimeoutError(
                f"{self.port}: telemetry did not show {what} within {timeout:g} s"
            ) from None

    async def wait_for(self, predicate: Callable[[Telemetry], bool], timeout: float) -> Telemetry:
        """Wait for telemetry that satisfies ``predicate`` and return it.

        The latest frame counts, so a condition that already holds returns at once.
        Example: ``await robot.wait_for(lambda t: t.docking is DockingState.DOCKED, 60)``.

        Args:
            predicate: Called with each `Telemetry`.
            timeout: Seconds (finite); the wait always ends.

        Raises:
            TimeoutError: No frame satisfied ``predicate`` in time.
            ValueError: ``timeout`` is not a finite number > 0.
            ConnectionLostError: The link dropped (without ``reconnect``).
        """
        telemetry: Telemetry = await self._first_match(
            self._telemetry, predicate, timeout, "telemetry"
        )
        return telemetry

    async def enable_telemetry(self, enabled: bool = True) -> None:
        """Switch the 50 Hz telemetry stream on or off (0x01). On at power-up."""
        await self._send(self._encoder.set_telemetry(enabled))

    async def enable_power_telemetry(self, enabled: bool = True) -> None:
        """Switch the 20 Hz driver current/voltage stream on or off (0xB1)."""
        await self._send(self._encoder.set_power_telemetry(enabled))
