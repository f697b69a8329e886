"""Dead reckoning from the velocities a device reports: a pure integrator, no I/O.

Each sample carries the velocity the device measured and the time it arrived. Between
two samples the robot is taken to have moved with the velocity of the *newer* one (the
device reports what it measured over the interval that just ended), along the exact
arc for that linear and angular velocity, so the result does not depend on how often
samples come: ten samples 20 ms apart and one sample 200 ms later give the same pose
for the same motion. A dropped frame therefore costs nothing but resolution; a gap
longer than ``max_gap`` (a stalled link, a reconnect) is not integrated at all, because
the velocity across it is unknown: the pose picks up from the next sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .construct import frozen_builder
from .validation import check_real

__all__ = ["Odometry", "OdometryIntegrator", "wrap_angle"]


@dataclass(frozen=True, slots=True)
class Odometry:
    """A pose and velocity in the odometry frame (where `reset` put the robot).

    Attributes:
        x: Forward of the starting pose (m).
        y: Left of the starting pose (m).
        heading: Counter-clockwise from the starting heading (rad), wrapped to
            ``(-pi, pi]``.
        linear: Linear velocity of the sample (m/s).
        angular: Angular velocity of the sample (rad/s).
        timestamp: ``time.monotonic()`` of the sample.
    """

    x: float
    y: float
    heading: float
    linear: float
    angular: float
    timestamp: float

    def distance_to(self, x: float, y: float) -> float:
        """Straight-line distance (m) from this pose to the point ``(x, y)``."""
        return math.hypot(x - self.x, y - self.y)


# One Odometry per velocity sample: built the cheap way (see protocol/_fast.py).
_build = frozen_builder(Odometry)


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped to ``(-pi, pi]``."""
    wrapped = math.remainder(angle, math.tau)
    return math.pi if wrapped == -math.pi else wrapped


class OdometryIntegrator:
    """Integrates ``(linear, angular, timestamp)`` samples into a pose.

    Args:
        max_gap: Longest interval (s) to integrate across; longer gaps are skipped.
    """

    def __init__(self, max_gap: float = 0.5) -> None:
        self.max_gap = check_real(max_gap, "max_gap", low=0, low_open=True, unit="s")
        self.x = 0.0
        self.y = 0.0
        self._heading = 0.0  # unwrapped, so many turns integrate without loss
        self._last: float | None = None
        self._sample: tuple[float, float, float] | None = None
        #: Gaps longer than ``max_gap`` that were not integrated.
        self.skipped_gaps = 0

    def reset(self, x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> None:
        """Put the robot at ``(x, y, heading)``; the next sample starts from there."""
        self.x, self.y, self._heading = float(x), float(y), float(heading)
        self._last = None

    def update(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> Odometry:
        """Advance to ``timestamp`` with this sample's velocity; return the new pose.

        Args:
            linear: Measured linear velocity (m/s).
            angular: Measured angular velocity (rad/s).
            timestamp: When the sample arrived (s, monotonic).
            heading: An absolute heading change to use instead of integrating
                ``angular`` (for a gyro-integrated heading), or ``None``.
        """
        self.advance(linear, angular, timestamp, heading)
        return _build(self.x, self.y, wrap_angle(self._heading), linear, angular, timestamp)

    def advance(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> None:
        """`update` without building the [`Odometry`][chassis_sdk.Odometry] (see `current`):
        the device integrates every sample, and builds a pose only for someone."""
        last = self._last
        self._last = timestamp
        self._sample = (linear, angular, timestamp)
        if last is not None:
            dt = timestamp - last
            if dt > self.max_gap:
                self.skipped_gaps += 1
            elif dt > 0:
                self._advance(linear, angular, dt, heading)

    def current(self) -> Odometry | None:
        """The pose now, with the last sample's velocity and time (``None`` before the
        first sample)."""
        sample = self._sample
        if sample is None:
            return None
        return _build(self.x, self.y, wrap_angle(self._heading), *sample)

    def _advance(self, v: float, w: float, dt: float, heading: float | None) -> None:
        h0 = self._heading
        h1 = h0 + w * dt if heading is None else heading
        # The exact arc, written as its chord: length v*dt*sin(a)/a with a half the
        # turn, along the mid heading. The same as (v*dt/turn)*(sin h1 - sin h0) but
        # without its cancellation, which lost nanometres on a nearly straight arc
        # (and so made one sample and three of the same motion disagree).
        half = (h1 - h0) / 2
        chord = v * dt * (math.sin(half) / half if half else 1.0)
        mid = h0 + half
        self.x += chord * math.cos(mid)
        self.y += chord * math.sin(mid)
        self._heading = h1

    @property
    def heading(self) -> float:
        """The integrated heading, unwrapped (rad)."""
        return self._heading
