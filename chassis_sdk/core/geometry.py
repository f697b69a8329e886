"""A wheeled base's size: what a robot description (the ROS 2 bridge's URDF) and the
wheels' joint states are made from. A device reports it (`Device.geometry`), or a user
gives it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from .validation import check_real

__all__ = ["FOUR_WHEELS", "Geometry"]

#: The wheels of a four-wheel base, in the order of a chassis's ``WheelSpeeds``.
FOUR_WHEELS: Final = ("front_left", "front_right", "rear_left", "rear_right")


@dataclass(frozen=True)
class Geometry:
    """A four-wheel base's size, lengths in metres.

    Attributes:
        track_width: Between the left and the right wheels' centres.
        wheelbase: Between the front and the rear axles.
        wheel_radius: A wheel's radius.
        wheels: The wheels' names (`FOUR_WHEELS`): ``front``/``rear`` and
            ``left``/``right`` place each.

    Raises:
        TypeError, ValueError: A length that is not a positive finite number; a wheel
            name that does not say front or rear and left or right.
    """

    track_width: float
    wheelbase: float
    wheel_radius: float
    wheels: tuple[str, ...] = FOUR_WHEELS

    def __post_init__(self) -> None:
        for name in ("track_width", "wheelbase", "wheel_radius"):
            value = check_real(getattr(self, name), name, low=0, low_open=True, high=100, unit="m")
            object.__setattr__(self, name, float(value))
        for wheel in self.wheels:
            self.place(wheel)  # raises on a name that does not place it

    def place(self, wheel: str) -> tuple[float, float]:
        """Where ``wheel``'s centre is from the base's centre: (x forward, y left), m.

        Raises:
            ValueError: The name says neither front nor rear, or neither left nor right.
        """
        x = self.wheelbase / 2 if "front" in wheel else -self.wheelbase / 2
        y = self.track_width / 2 if "left" in wheel else -self.track_width / 2
        if ("front" in wheel) == ("rear" in wheel) or ("left" in wheel) == ("right" in wheel):
            raise ValueError(f"a wheel's name says front or rear and left or right: {wheel!r}")
        return x, y
