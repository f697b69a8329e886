"""A battery's state of charge from its voltage: a sans-IO estimator, no clock of its own.

Why it is shaped so. A pack's terminal voltage is its open-circuit voltage (OCV, a
function of the state of charge that each chemistry tabulates) minus the sag under the
current it delivers (``I * R``, R the internal resistance). A base reports the voltage
only in 0.1 V steps, and a chassis the wheel currents only with its power telemetry,
so the estimate

* undoes the sag when the current is known (``V_ocv = V + I * R``, R configured or
  estimated from the voltage steps that follow current steps);
* does not use a reading taken under load with no current to undo it (the caller says
  ``loaded=True``), nor a heavy draw before R is known: such a reading would report a
  pack emptier than it is;
* counts the charge drawn between readings when the capacity is known, so that the
  estimate follows a discharge at once and the voltage only corrects its drift;
* smooths the voltage's verdict exponentially with a time constant (dt-aware, so
  irregular readings weigh what their interval is worth) against the 0.1 V steps;
* is ``None`` until it is known: until ``warmup`` seconds and ``min_readings`` usable
  readings have gone by, never a made-up number; then clamped to 0..100;
* classifies the result as `BatteryLevel` ``OK``, ``LOW`` or ``CRITICAL`` with a
  hysteresis, so a pack sagging around a threshold does not chatter.

The curves are per cell; the pack is ``cells`` in series.
"""

from __future__ import annotations

import bisect
import enum
import math
from collections.abc import Sequence
from typing import Final, Literal

from .validation import check_int, check_real

__all__ = ["OCV_CURVES", "BatteryLevel", "BatteryModel", "Chemistry", "ocv", "percent_of"]

Chemistry = Literal["lifepo4", "li-ion", "lead-acid"]

#: Open-circuit voltage per cell (V, at rest, about 25 °C) against the state of charge
#: (percent), ascending in both. These are the *typical* rested-OCV tables that battery
#: makers and references publish; a given pack differs by tens of millivolts, so pass
#: your own ``curve`` when you have its datasheet or a measured one.
#:
#: * ``lifepo4``: the widely circulated LiFePO4 chart for 12.8 V (4S) packs, divided by
#:   four (13.6 V full at rest, 13.0 V at 40 %, 12.8 V at 20 %, 12.0 V at 10 %, 10.0 V
#:   empty). Its plateau from 30 % to 90 % spans only 0.13 V per cell: on an 8S pack
#:   read in 0.1 V steps, voltage alone resolves it coarsely; the capacity (charge
#:   counting) is what keeps the estimate close there.
#: * ``li-ion``: the typical rested OCV of an NMC/LCO 18650-type cell (4.20 V full,
#:   about 3.8 V at half charge, 3.0 V empty).
#: * ``lead-acid``: the usual rested OCV chart of a 12 V flooded/AGM battery (12.7 V
#:   full, 12.06 V at half, 11.3 V at 10 %, 10.5 V empty, as tabulated by Battery
#:   University's "BU-903: How to Measure State-of-charge" and makers' charts), per cell
#:   (divided by six).
OCV_CURVES: Final[dict[str, tuple[tuple[float, float], ...]]] = {
    "lifepo4": (
        (2.500, 0.0),
        (3.000, 10.0),
        (3.200, 20.0),
        (3.225, 30.0),
        (3.250, 40.0),
        (3.260, 50.0),
        (3.275, 60.0),
        (3.300, 70.0),
        (3.325, 80.0),
        (3.350, 90.0),
        (3.400, 100.0),
    ),
    "li-ion": (
        (3.000, 0.0),
        (3.450, 5.0),
        (3.680, 10.0),
        (3.740, 20.0),
        (3.770, 30.0),
        (3.790, 40.0),
        (3.820, 50.0),
        (3.870, 60.0),
        (3.920, 70.0),
        (3.980, 80.0),
        (4.060, 90.0),
        (4.200, 100.0),
    ),
    "lead-acid": (
        (1.7500, 0.0),
        (1.8850, 10.0),
        (1.9300, 20.0),
        (1.9583, 30.0),
        (1.9833, 40.0),
        (2.0100, 50.0),
        (2.0333, 60.0),
        (2.0533, 70.0),
        (2.0700, 80.0),
        (2.0833, 90.0),
        (2.1167, 100.0),
    ),
}


class BatteryLevel(enum.IntEnum):
    """How low the charge is, in order of severity."""

    OK = 0  #: at or above ``low`` (plus the hysteresis, coming back)
    LOW = 1  #: below ``low``
    CRITICAL = 2  #: below ``critical``


def _check_curve(curve: object) -> tuple[tuple[float, float], ...]:
    if isinstance(curve, str | bytes) or not isinstance(curve, Sequence):
        raise TypeError(f"curve must be a sequence of (volts, percent) pairs, got {curve!r}")
    if len(curve) < 2:
        raise ValueError(f"curve must be at least two (volts, percent) pairs, got {curve!r}")
    points: list[tuple[float, float]] = []
    for point in curve:
        if isinstance(point, str | bytes) or not isinstance(point, Sequence):
            raise TypeError(f"curve points must be (volts, percent) pairs, got {point!r}")
        if len(point) != 2:
            raise ValueError(f"curve points must be (volts, percent) pairs, got {point!r}")
        volts = check_real(point[0], "curve volts", low=0, low_open=True, unit="V")
        percent = check_real(point[1], "curve percent", low=0, high=100)
        if points and not (volts > points[-1][0] and percent > points[-1][1]):
            raise ValueError(
                f"curve must rise in volts and percent, got {point!r} after {points[-1]!r}"
            )
        points.append((volts, percent))
    return tuple(points)


def percent_of(volts_per_cell: float, curve: Sequence[tuple[float, float]]) -> float:
    """The state of charge (0..100) of an open-circuit voltage per cell, interpolated
    linearly on ``curve`` and clamped at its ends."""
    if volts_per_cell <= curve[0][0]:
        return curve[0][1]
    if volts_per_cell >= curve[-1][0]:
        return curve[-1][1]
    i = bisect.bisect_right([v for v, _ in curve], volts_per_cell)
    (v0, p0), (v1, p1) = curve[i - 1], curve[i]
    return p0 + (p1 - p0) * (volts_per_cell - v0) / (v1 - v0)


def ocv(percent: float, curve: Sequence[tuple[float, float]]) -> float:
    """The open-circuit voltage per cell of a state of charge: the inverse of
    `percent_of` on ``curve`` (``percent`` clamped to the curve's span)."""
    if percent <= curve[0][1]:
        return curve[0][0]
    if percent >= curve[-1][1]:
        return curve[-1][0]
    i = bisect.bisect_right([p for _, p in curve], percent)
    (v0, p0), (v1, p1) = curve[i - 1], curve[i]
    return v0 + (v1 - v0) * (percent - p0) / (p1 - p0)


class BatteryModel:
    """A pack's state of charge from its voltage (and current, when known).

    Feed it every reading with `update`; it returns the percentage, or ``None``
    while it is not known. It is sans-IO: the caller passes the time of each reading.

    Examples:
        >>> model = BatteryModel("li-ion", cells=7, warmup=0.0, min_readings=1)
        >>> round(model.update(26.74, now=0.0) or 0.0)
        50

    Args:
        chemistry: ``"lifepo4"``, ``"li-ion"`` or ``"lead-acid"``: which curve of
            `OCV_CURVES` (unless ``curve`` is given).
        cells: Cells in series.
        capacity_ah: The pack's capacity (Ah). With it and a current, the charge drawn
            between readings is counted, and the voltage corrects the count slowly.
        internal_resistance: The pack's resistance (Ω) for the sag ``I * R``; ``None``
            estimates it from the voltage steps that follow current steps.
        curve: Your own ``[(volts_per_cell, percent), ...]``, rising in both.
        smoothing: Time constant (s) of the exponential smoothing of the voltage's
            verdict.
        warmup: Seconds of usable readings before a percentage is given.
        min_readings: Usable readings before a percentage is given.
        low: Percent below which the level is ``LOW``.
        critical: Percent below which the level is ``CRITICAL``.
        hysteresis: Percentage points above a threshold needed to leave its level.
        rest_current: Amperes below which a reading counts as at rest when R is not yet
            known (above it, the reading is not used until R is).

    Raises:
        ValueError: An unknown chemistry or an option out of range.
    """

    #: Amperes of current change between two readings that make a resistance sample.
    STEP_CURRENT: Final = 2.0
    #: Longest interval (s) between two readings that make a resistance sample.
    STEP_INTERVAL: Final = 0.25
    #: Sum of squared current steps (A²) before the estimated R is trusted.
    TRUSTED_EXCITATION: Final = 400.0

    def __init__(
        self,
        chemistry: Chemistry = "lifepo4",
        *,
        cells: int = 8,
        capacity_ah: float | None = None,
        internal_resistance: float | None = None,
        curve: Sequence[tuple[float, float]] | None = None,
        smoothing: float = 30.0,
        warmup: float = 3.0,
        min_readings: int = 5,
        low: float = 20.0,
        critical: float = 10.0,
        hysteresis: float = 5.0,
        rest_current: float = 2.0,
    ) -> None:
        if not isinstance(chemistry, str):
            raise TypeError(
                f"chemistry must be a string, one of {sorted(OCV_CURVES)}, got {chemistry!r}"
            )
        if curve is None:
            if chemistry not in OCV_CURVES:
                raise ValueError(
                    f"chemistry must be one of {sorted(OCV_CURVES)}, got {chemistry!r}"
                )
            curve = OCV_CURVES[chemistry]
        self.chemistry = chemistry
        self.curve = _check_curve(curve)
        self.cells = check_int(cells, "cells", low=1)
        self.capacity_ah = (
            None
            if capacity_ah is None
            else check_real(capacity_ah, "capacity_ah", low=0, low_open=True, unit="Ah")
        )
        self.configured_resistance = (
            None
            if internal_resistance is None
            else check_real(internal_resistance, "internal_resistance", low=0, unit="ohm")
        )
        self.smoothing = check_real(smoothing, "smoothing", low=0, low_open=True, unit="s")
        self.warmup = check_real(warmup, "warmup", low=0, unit="s")
        self.min_readings = check_int(min_readings, "min_readings", low=1)
        self.low = check_real(low, "low", low=0, high=100)
        self.critical = check_real(critical, "critical", low=0, high=100)
        if self.critical > self.low:
            raise ValueError(f"critical must be <= low, got {critical!r} > {low!r}")
        self.hysteresis = check_real(hysteresis, "hysteresis", low=0, high=100)
        self.rest_current = check_real(rest_current, "rest_current", low=0, unit="A")
        self.reset()

    def reset(self) -> None:
        """Forget every reading (a pack swapped or charged while unseen)."""
        self._estimate: float | None = None  # internal, from the first usable reading
        self._first: float | None = None  # time of the first usable reading
        self._usable = 0
        self._last_time: float | None = None
        self._last_current: float | None = None
        self._last_voltage: float | None = None
        self._r_num = 0.0  # least squares of R over current steps: sum(-dV*dI), sum(dI²)
        self._r_den = 0.0
        self.level: BatteryLevel | None = None
        self.percentage: float | None = None

    @property
    def internal_resistance(self) -> float | None:
        """The resistance (Ω) used for the sag: the configured one, else the estimate
        once the current steps seen are enough to trust it, else ``None``."""
        if self.configured_resistance is not None:
            return self.configured_resistance
        if self._r_den < self.TRUSTED_EXCITATION:
            return None
        return min(1.0, max(0.0, self._r_num / self._r_den))

    def percent_at_rest(self, voltage: float) -> float:
        """The state of charge the curve gives a pack voltage at rest (no smoothing)."""
        return percent_of(voltage / self.cells, self.curve)

    def update(
        self,
        voltage: float,
        current: float | None = None,
        *,
        now: float,
        loaded: bool = False,
    ) -> float | None:
        """One reading; the percentage now (0..100), or ``None`` while not known.

        Args:
            voltage: Terminal voltage of the pack (V).
            current: Current drawn from it (A; negative while charging), if measured.
            now: When the reading was taken (s, any monotonic clock).
            loaded: The caller knows the pack is under load but has no current to undo
                the sag with (a base accelerating without power telemetry): the
                reading is not used (charge counting goes on if it can).

        Raises:
            ValueError: ``voltage`` or ``current`` is not a finite number, or the
                voltage is negative.
        """
        voltage = check_real(voltage, "voltage", low=0, unit="V")
        if current is not None:
            current = check_real(current, "current", unit="A")
        dt = 0.0 if self._last_time is None else max(0.0, now - self._last_time)
        self._learn_resistance(voltage, current, dt)
        self._last_time, self._last_voltage, self._last_current = now, voltage, current
        if self._estimate is not None and current is not None and self.capacity_ah is not None:
            drawn = current * dt / 3600.0 / self.capacity_ah * 100.0
            self._estimate = min(100.0, max(0.0, self._estimate - drawn))
        reading = self._at_rest(voltage, current, loaded)
        if reading is not None:
            if self._estimate is None:
                self._estimate, self._first = reading, now
            elif self._usable < self.min_readings or now - (self._first or now) < self.warmup:
                self._estimate += (reading - self._estimate) / (self._usable + 1)  # a mean
            else:
                alpha = 1.0 - math.exp(-dt / self.smoothing)
                self._estimate += alpha * (reading - self._estimate)
            self._usable += 1
        warm = (
            self._estimate is not None
            and self._usable >= self.min_readings
            and now - (self._first if self._first is not None else now) >= self.warmup
        )
        if warm and self._estimate is not None:
            self.percentage = min(100.0, max(0.0, self._estimate))
            self.level = self._level(self.percentage)
        return self.percentage

    def _at_rest(self, voltage: float, current: float | None, loaded: bool) -> float | None:
        """The state of charge this reading shows, with the sag undone, or ``None``
        when it cannot be used."""
        if current is None:
            return None if loaded else self.percent_at_rest(voltage)
        r = self.internal_resistance
        if r is None:
            return self.percent_at_rest(voltage) if abs(current) <= self.rest_current else None
        return self.percent_at_rest(voltage + current * r)

    def _learn_resistance(self, voltage: float, current: float | None, dt: float) -> None:
        last_v, last_i = self._last_voltage, self._last_current
        if current is None or last_v is None or last_i is None or not 0 < dt <= self.STEP_INTERVAL:
            return
        di = current - last_i
        if abs(di) >= self.STEP_CURRENT:
            self._r_num -= (voltage - last_v) * di
            self._r_den += di * di

    def _level(self, p: float) -> BatteryLevel:
        level, h = self.level or BatteryLevel.OK, self.hysteresis
        if p < self.critical or (level is BatteryLevel.CRITICAL and p < self.critical + h):
            return BatteryLevel.CRITICAL
        if p < self.low or (level is not BatteryLevel.OK and p < self.low + h):
            return BatteryLevel.LOW
        return BatteryLevel.OK

    def __repr__(self) -> str:
        return (
            f"BatteryModel({self.chemistry!r}, cells={self.cells}, "
            f"capacity_ah={self.capacity_ah!r}, "
            f"internal_resistance={self.configured_resistance!r})"
        )
