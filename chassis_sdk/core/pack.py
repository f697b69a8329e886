"""A simulated battery pack, for the firmware models: a charge that the current drains,
an open-circuit voltage from the chemistry's curve, and a sag under load.

The firmware models (``chassis_sdk.devices.*.firmware``) own one when their spec asks
for it; what they report is its terminal voltage, in the device's own resolution. The
curves are `chassis_sdk.core.battery.OCV_CURVES` unless the spec gives another
(a pack whose curve differs from the one an estimator assumes, for instance).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from .battery import OCV_CURVES, Chemistry, ocv, percent_of
from .validation import check_int, check_real

__all__ = ["Pack", "PackSpec"]


@dataclass(frozen=True, slots=True)
class PackSpec:
    """A simulated pack's parameters.

    Attributes:
        chemistry: Which curve of ``OCV_CURVES`` (unless ``curve``).
        cells: Cells in series.
        capacity_ah: Charge when full (Ah).
        internal_resistance: Ω: the terminal voltage sags by ``I * R``.
        charge: State of charge at power-up (percent).
        curve: Its own ``(volts_per_cell, percent)`` curve, rising in both.
    """

    chemistry: Chemistry = "lifepo4"
    cells: int = 8
    capacity_ah: float = 20.0
    internal_resistance: float = 0.03
    charge: float = 100.0
    curve: Sequence[tuple[float, float]] | None = None

    def __post_init__(self) -> None:
        if self.curve is None and self.chemistry not in OCV_CURVES:
            raise ValueError(
                f"chemistry must be one of {sorted(OCV_CURVES)}, got {self.chemistry!r}"
            )
        check_int(self.cells, "cells", low=1)
        check_real(self.capacity_ah, "capacity_ah", low=0, low_open=True, unit="Ah")
        check_real(self.internal_resistance, "internal_resistance", low=0, unit="ohm")
        check_real(self.charge, "charge", low=0, high=100)


class Pack:
    """The state of a simulated pack: its true charge (percent), drained by
    `draw`; `terminal_voltage` is what a voltmeter on it reads."""

    def __init__(self, spec: PackSpec) -> None:
        self.spec = spec
        self.curve = tuple(spec.curve) if spec.curve is not None else OCV_CURVES[spec.chemistry]
        self.charge = float(spec.charge)
        #: Ampere-hours drawn since power-up.
        self.drawn_ah = 0.0

    def draw(self, current: float, dt: float) -> None:
        """``current`` amperes (negative: charging) for ``dt`` seconds."""
        ah = current * dt / 3600.0
        self.drawn_ah += ah
        self.charge = min(100.0, max(0.0, self.charge - ah / self.spec.capacity_ah * 100.0))

    @property
    def open_voltage(self) -> float:
        """The open-circuit voltage of the pack at its charge (V)."""
        return ocv(self.charge, self.curve) * self.spec.cells

    def terminal_voltage(self, current: float) -> float:
        """What the pack's terminals read while ``current`` amperes flow (never < 0)."""
        return max(0.0, self.open_voltage - current * self.spec.internal_resistance)

    def set_open_voltage(self, voltage: float) -> None:
        """Set the charge to the one this open-circuit voltage shows."""
        self.charge = percent_of(voltage / self.spec.cells, self.curve)
