"""The sans-IO base of every firmware model: what a simulator serves, and what the
models of the devices share (a command decoder, the log of commands, rebooting).

Pure: no asyncio, no clock of its own (every call is given ``now``). The server that
puts a model on a pty or TCP is `chassis_sdk.sim.SimulatorServer`.
"""

from __future__ import annotations

import abc
import math
from collections import deque
from typing import Generic, Protocol, TypeVar

from .framing import DecoderStats, FrameDecoder
from .validation import check_real

__all__ = ["Firmware", "FirmwareModel", "Obstacles", "check_fits", "check_motion", "next_slot"]


def next_slot(previous: float, period: float, now: float) -> float:
    """The next boundary of the schedule ``previous + k * period`` after ``now``.

    A firmware that fell behind (a busy loop) skips the missed slots rather than sending
    a burst, as a real timer interrupt would.
    """
    nxt = previous + period
    return nxt if nxt > now else now + period


class Obstacles(Protocol):
    """What a firmware model asks of a world (`chassis_sdk.sim.World` is one): moving a
    ``length`` x ``width`` box from pose ``start`` towards ``end`` (x, y m, heading
    rad), where it stops, and where on the box it touched a wall (x forward, y left,
    metres) or ``None``."""

    def sweep(
        self,
        start: tuple[float, float, float],
        end: tuple[float, float, float],
        length: float,
        width: float,
    ) -> tuple[tuple[float, float, float], tuple[float, float] | None]: ...


def check_fits(
    what: str,
    world: Obstacles | None,
    pose: tuple[float, float, float],
    footprint: tuple[float, float],
) -> None:
    """Raise ``ValueError`` if ``what``'s box (``footprint``: length, width) at ``pose``
    touches a wall of ``world``."""
    if world is None:
        return
    length, width = footprint
    if world.sweep(pose, pose, length, width)[1] is not None:
        raise ValueError(
            f"{what} ({length:g} x {width:g} m) at ({pose[0]:g}, {pose[1]:g}) touches "
            "a wall of this world: make the world bigger"
        )


def check_motion(
    wheel_diameter_error: float,
    turn_slip: float,
    slip_noise: float,
    footprint: tuple[float, float] | None,
) -> None:
    """The checks of a simulated base's motion errors and box (a spec's
    ``__post_init__``): ``ValueError`` for one out of range."""
    check_real(wheel_diameter_error, "wheel_diameter_error", low=-0.5, high=0.5)
    check_real(turn_slip, "turn_slip", low=0, high=0.9)
    check_real(slip_noise, "slip_noise", low=0, high=0.5)
    if footprint is not None:
        length, width = footprint
        check_real(length, "footprint length", low=0, low_open=True, unit="m")
        check_real(width, "footprint width", low=0, low_open=True, unit="m")


class Firmware(Protocol):
    """What the server needs of a firmware model."""

    def receive(self, data: bytes, now: float) -> bytes: ...

    def poll(self, now: float) -> bytes: ...

    def next_deadline(self) -> float: ...

    def on_connect(self, now: float) -> None: ...

    def reset(self, now: float, downtime: float = ...) -> None: ...


C = TypeVar("C")


class FirmwareModel(abc.ABC, Generic[C]):
    """What every sans-IO firmware model shares: a command decoder, the log of commands
    received, and rebooting (silent for a while, then the power-up state).

    A device's model implements `_power_on` (its power-up state, with a fresh
    ``_decoder`` of host commands), `_execute` (one command, returning any
    immediate reply), `on_connect`, `poll` and `next_deadline`; its
    ``__init__`` calls ``_power_on()`` once its own settings are in place.
    """

    _decoder: FrameDecoder[C]

    def __init__(self) -> None:
        #: Every command received, newest last, with its arrival time.
        self.received: deque[tuple[float, C]] = deque(maxlen=10_000)
        #: Times :meth:`reset` was called.
        self.resets = 0
        self._boot_until = -math.inf

    @abc.abstractmethod
    def _power_on(self) -> None:
        """Enter the power-up state (also after a reset)."""

    @abc.abstractmethod
    def _execute(self, cmd: C, now: float) -> bytes:
        """Carry out one host command; return the immediate reply, if any."""

    @abc.abstractmethod
    def on_connect(self, now: float) -> None:
        """Start the clocks (the simulator starts or a client connects)."""

    @abc.abstractmethod
    def poll(self, now: float) -> bytes:
        """Advance the model to ``now``; return the periodic frames that fell due."""

    @abc.abstractmethod
    def next_deadline(self) -> float:
        """When [`poll`][chassis_sdk.core.firmware.FirmwareModel.poll] next has something to do."""

    def booting(self, now: float) -> bool:
        """True while a reset keeps the firmware silent and deaf."""
        return now < self._boot_until

    def reset(self, now: float, downtime: float = 0.5) -> None:
        """Reboot, as a brown-out or watchdog reset would: for ``downtime`` seconds it
        sends nothing and loses what the host sends; then it is in its power-up state
        (sequence numbers from 0, latched faults cleared, motors stopped)."""
        self.resets += 1
        self._power_on()
        self._boot_until = now + downtime
        self.on_connect(self._boot_until)

    def receive(self, data: bytes, now: float) -> bytes:
        """Handle bytes from the host; return the immediate replies."""
        if self.booting(now):
            return b""  # rebooting: nobody is listening
        out = bytearray()
        for cmd in self._decoder.feed(data, now):
            self.received.append((now, cmd))
            out += self._execute(cmd, now)
        return bytes(out)

    @property
    def decoder_stats(self) -> DecoderStats:
        """Stats of the firmware's command decoder (bytes dropped, checksum errors...)."""
        return self._decoder.stats
