"""Odometry calibration factors: what the robot really did over what it reported.

Skid-steer odometry is never right out of the box: the wheels' real diameter is not
the data sheet's (every distance is off by the same ratio), and a skid-steer base
slips sideways in a turn, so the heading it reports from its encoders turns faster
than the robot does (its effective track is wider than the geometric one). Two
factors, as ``diff_drive_controller``'s ``wheel_radius_multiplier`` and
``wheel_separation_multiplier``, correct both:

* ``linear_scale``: true distance = reported distance x ``linear_scale``;
* ``angular_scale``: true rotation = reported rotation x ``angular_scale``. It is the
  whole correction of the reported angular velocity (the wheel diameter's share
  included), that is ``wheel_radius_multiplier / wheel_separation_multiplier``.

Pure: no I/O, no clock. ``chassis-sdk calibrate`` measures them and writes them to the
profile's ``[calibration]`` table, keyed by these field names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .validation import check_real

__all__ = ["SCALE_RANGE", "Calibration", "combined_scale"]

#: The factors a calibration may hold: beyond them, the reading was wrong (a tape
#: measure read in the wrong unit, a turn counted twice), not the robot.
SCALE_RANGE = (0.5, 2.0)


@dataclass(frozen=True, slots=True)
class Calibration:
    """Calibration factors applied to odometry and to wheel-mode commands.

    Attributes:
        linear_scale: True distance over reported distance (a wheel diameter error):
            the reported linear velocity (and each wheel speed) is multiplied by it,
            and wheel-mode commands are divided by it so the true wheel speed is the
            one asked for.
        angular_scale: True rotation over reported rotation (skid slip in turns, and
            the wheel diameter): the reported angular velocity is multiplied by it.

    Raises:
        ValueError: A factor is not a finite number within `SCALE_RANGE`.

    Examples:
        >>> cal = Calibration(linear_scale=1.04, angular_scale=0.83)
        >>> cal.linear(0.5), cal.angular(1.0)
        (0.52, 0.83)
    """

    linear_scale: float = 1.0
    angular_scale: float = 1.0

    def __post_init__(self) -> None:
        low, high = SCALE_RANGE
        for name in ("linear_scale", "angular_scale"):
            value = check_real(getattr(self, name), name, low=low, high=high)
            object.__setattr__(self, name, value)

    @property
    def is_identity(self) -> bool:
        """Whether both factors are 1 (nothing is corrected)."""
        return self.linear_scale == 1.0 and self.angular_scale == 1.0

    def linear(self, reported: float) -> float:
        """The true linear velocity (or distance) of a ``reported`` one."""
        return reported * self.linear_scale

    def angular(self, reported: float) -> float:
        """The true angular velocity (or rotation) of a ``reported`` one."""
        return reported * self.angular_scale

    def wheel_command(self, wanted: float) -> float:
        """The wheel speed to send so the wheel's true speed is ``wanted`` (m/s)."""
        return wanted / self.linear_scale


def combined_scale(current: float, reported: float, measured: float, name: str) -> float:
    """The new factor from one calibration run: the factor in use (``current``, which
    the device applied to what it ``reported``) corrected by ``measured / reported``,
    so running a calibration again converges rather than starting over.

    Args:
        current: The factor in use while the run was reported.
        reported: What the calibrated odometry measured (distance or rotation, > 0).
        measured: What was really measured, in the same unit (> 0).
        name: The factor's name, for the error message.

    Raises:
        ValueError: ``reported`` or ``measured`` is not a finite number > 0, or the
            new factor falls outside `SCALE_RANGE`.
    """
    current = check_real(current, name, low=SCALE_RANGE[0], high=SCALE_RANGE[1])
    reported = check_real(reported, "reported", low=0, low_open=True)
    measured = check_real(measured, "measured", low=0, low_open=True)
    factor = current * measured / reported
    low, high = SCALE_RANGE
    if not math.isfinite(factor) or not low <= factor <= high:
        raise ValueError(
            f"{name} would be {factor:.3f} (measured {measured:g} against {reported:g} "
            f"reported): outside {low:g}..{high:g}, so the measurement is not believable"
        )
    return factor
