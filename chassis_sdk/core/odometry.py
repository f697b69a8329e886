"""Dead reckoning from the velocities a device reports: a pure integrator, no I/O.

Each sample carries the velocity the device measured and the time it arrived. Between
two samples the robot is taken to have moved with the velocity of the *newer* one (the
device reports what it measured over the interval that just ended), along the exact
arc for that linear and angular velocity, so the result does not depend on how often
samples come: ten samples 20 ms apart and one sample 200 ms later give the same pose
for the same motion. A dropped frame therefore costs nothing but resolution; a gap
longer than ``max_gap`` (a stalled link, a reconnect) is not integrated at all, because
the velocity across it is unknown: the pose picks up from the next sample. Samples that
share one timestamp (frames that waited in the kernel while the event loop was held up,
read at once) share the interval since the sample before them, in order: during a
speed ramp the first of them alone would stand for the whole interval.
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


#: Samples `OdometryIntegrator.defer` holds before it integrates them all at once.
DEFER_LIMIT = 64

_Sample = tuple[float, float, float, "float | None"]


class OdometryIntegrator:
    """Integrates ``(linear, angular, timestamp)`` samples into a pose.

    A device integrates every velocity sample, but builds and reads a pose only when
    someone asks; `defer` takes a sample at the cost of appending it, and the samples
    are integrated, in order and with the same arithmetic, the next time anything
    reads or changes the integrator (or `DEFER_LIMIT` of them wait). A cold read path
    runs the integration at 50 Hz per device; run as one loop, it costs a fraction.

    Args:
        max_gap: Longest interval (s) to integrate across; longer gaps are skipped.
    """

    def __init__(self, max_gap: float = 0.5) -> None:
        self._max_gap = check_real(max_gap, "max_gap", low=0, low_open=True, unit="s")
        self._x = 0.0
        self._y = 0.0
        self._heading = 0.0  # unwrapped, so many turns integrate without loss
        self._last: float | None = None
        self._sample: tuple[float, float, float] | None = None
        self._skipped = 0
        self._deferred: list[_Sample] = []
        # The samples that share the last timestamp (one read), and the pose and time
        # before the first of them: see `_step`.
        self._burst: list[tuple[float, float, float | None]] | None = None
        self._burst_start: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    @property
    def x(self) -> float:
        """Forward of the starting pose (m)."""
        if self._deferred:
            self._catch_up()
        return self._x

    @property
    def y(self) -> float:
        """Left of the starting pose (m)."""
        if self._deferred:
            self._catch_up()
        return self._y

    @property
    def heading(self) -> float:
        """The integrated heading, unwrapped (rad)."""
        if self._deferred:
            self._catch_up()
        return self._heading

    @property
    def skipped_gaps(self) -> int:
        """Gaps longer than ``max_gap`` that were not integrated."""
        if self._deferred:
            self._catch_up()
        return self._skipped

    @property
    def max_gap(self) -> float:
        """Longest interval (s) integrated across (may be changed: the samples taken
        before the change are integrated under the old value)."""
        return self._max_gap

    @max_gap.setter
    def max_gap(self, value: float) -> None:
        if self._deferred:
            self._catch_up()
        self._max_gap = check_real(value, "max_gap", low=0, low_open=True, unit="s")

    def reset(self, x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> None:
        """Put the robot at ``(x, y, heading)``; the next sample starts from there."""
        if self._deferred:
            self._catch_up()
        self._x, self._y, self._heading = float(x), float(y), float(heading)
        self._last = None
        self._burst = None

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
        return _build(self._x, self._y, wrap_angle(self._heading), linear, angular, timestamp)

    def advance(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> None:
        """`update` without building the [`Odometry`][chassis_sdk.Odometry] (see `current`)."""
        if self._deferred:
            self._catch_up()
        self._step(linear, angular, timestamp, heading)

    def defer(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> None:
        """`advance`, later: the sample is kept, and integrated with the others kept
        before anything reads or changes the integrator."""
        deferred = self._deferred
        deferred.append((linear, angular, timestamp, heading))
        if len(deferred) >= DEFER_LIMIT:
            self._catch_up()

    def current(self) -> Odometry | None:
        """The pose now, with the last sample's velocity and time (``None`` before the
        first sample)."""
        if self._deferred:
            self._catch_up()
        sample = self._sample
        if sample is None:
            return None
        return _build(self._x, self._y, wrap_angle(self._heading), *sample)

    def _catch_up(self) -> None:
        """Integrate the samples kept, in order."""
        samples, self._deferred = self._deferred, []
        step = self._step
        for sample in samples:
            step(*sample)

    def _step(self, linear: float, angular: float, timestamp: float, heading: float | None) -> None:
        last = self._last
        self._last = timestamp
        self._sample = (linear, angular, timestamp)
        if last is None:
            return
        burst = self._burst
        if timestamp == last and burst is not None:
            # Another sample of the same read (frames that waited in the kernel while
            # the loop was held up): the interval since the sample before them is
            # shared among them in order, not given whole to the first.
            burst.append((linear, angular, heading))
            x, y, h, since = self._burst_start
            self._x, self._y, self._heading = x, y, h
            dt = (timestamp - since) / len(burst)
            for sample in burst:
                self._move(*sample, dt)
            return
        dt = timestamp - last
        self._burst = None
        if dt > self._max_gap:
            self._skipped += 1
        elif dt > 0:
            self._burst_start = (self._x, self._y, self._heading, last)
            self._burst = [(linear, angular, heading)]
            self._move(linear, angular, heading, dt)

    def _move(self, linear: float, angular: float, heading: float | None, dt: float) -> None:
        h0 = self._heading
        h1 = h0 + angular * dt if heading is None else heading
        # The exact arc, written as its chord: length v*dt*sin(a)/a with a half the
        # turn, along the mid heading. The same as (v*dt/turn)*(sin h1 - sin h0) but
        # without its cancellation, which lost nanometres on a nearly straight arc
        # (and so made one sample and three of the same motion disagree).
        half = (h1 - h0) / 2
        chord = linear * dt * (math.sin(half) / half if half else 1.0)
        mid = h0 + half
        self._x += chord * math.cos(mid)
        self._y += chord * math.sin(mid)
        self._heading = h1
