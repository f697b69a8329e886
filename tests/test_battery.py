"""The battery's state of charge: the sans-IO model (curves, sag compensation, smoothing,
warm-up, clamping, hysteresis; properties with hypothesis) and, through a real pty, the
estimate against the simulated pack's true charge while it discharges under driving."""

from __future__ import annotations

import functools
import itertools
import json
import math
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import anyio
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chassis_sdk import Chassis, EventKind, Reflex, RobotEvent, SafetyPolicy
from chassis_sdk.cli.monitor_command import monitor
from chassis_sdk.core.battery import (
    OCV_CURVES,
    BatteryLevel,
    BatteryModel,
    ocv,
    percent_of,
)
from chassis_sdk.devices import profile
from chassis_sdk.protocol import ChassisEncoder
from chassis_sdk.sim import (
    BoardSimulator,
    BoardSpec,
    ChassisFirmware,
    ChassisSimulator,
    ChassisSpec,
    PackSpec,
)

from .support.cli import cli
from .support.helpers import until

CHEMISTRIES = sorted(OCV_CURVES)


def warm(model: BatteryModel, voltage: float, seconds: float = 4.0, rate: float = 10.0) -> float:
    """Feed a steady reading for ``seconds`` at ``rate`` Hz; the time after it."""
    now = 0.0
    for _ in range(round(seconds * rate)):
        model.update(voltage, now=now)
        now += 1 / rate
    return now


# --- curves ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("chemistry", "volts", "percent"),
    [
        pytest.param("lifepo4", 3.40, 100.0, id="lifepo4-full"),
        pytest.param("lifepo4", 3.26, 50.0, id="lifepo4-half"),
        pytest.param("lifepo4", 3.20, 20.0, id="lifepo4-20"),
        pytest.param("lifepo4", 3.10, 15.0, id="lifepo4-interpolated"),
        pytest.param("lifepo4", 2.50, 0.0, id="lifepo4-empty"),
        pytest.param("li-ion", 4.20, 100.0, id="li-ion-full"),
        pytest.param("li-ion", 3.82, 50.0, id="li-ion-half"),
        pytest.param("li-ion", 3.71, 15.0, id="li-ion-interpolated"),
        pytest.param("li-ion", 3.00, 0.0, id="li-ion-empty"),
        pytest.param("lead-acid", 12.70 / 6, 100.0, id="lead-acid-full"),
        pytest.param("lead-acid", 12.06 / 6, 50.0, id="lead-acid-half"),
        pytest.param("lead-acid", 10.50 / 6, 0.0, id="lead-acid-empty"),
        pytest.param("li-ion", 4.35, 100.0, id="above-full-clamps"),
        pytest.param("li-ion", 2.50, 0.0, id="below-empty-clamps"),
    ],
)
def test_curve_vectors(chemistry: str, volts: float, percent: float) -> None:
    assert percent_of(volts, OCV_CURVES[chemistry]) == pytest.approx(percent, abs=0.05)


@pytest.mark.parametrize("chemistry", CHEMISTRIES)
def test_curves_rise_and_span_empty_to_full(chemistry: str) -> None:
    curve = OCV_CURVES[chemistry]
    assert curve[0][1] == 0.0
    assert curve[-1][1] == 100.0
    for (v0, p0), (v1, p1) in itertools.pairwise(curve):
        assert v1 > v0
        assert p1 > p0


@pytest.mark.parametrize("chemistry", CHEMISTRIES)
@pytest.mark.parametrize("percent", [0.0, 7.5, 33.0, 50.0, 91.0, 100.0])
def test_ocv_inverts_percent_of(chemistry: str, percent: float) -> None:
    curve = OCV_CURVES[chemistry]
    assert percent_of(ocv(percent, curve), curve) == pytest.approx(percent, abs=1e-9)


def test_pack_voltage_is_per_cell_times_cells() -> None:
    model = BatteryModel("lifepo4", cells=8)
    assert model.percent_at_rest(8 * 3.26) == pytest.approx(50.0)
    model = BatteryModel("lead-acid", cells=6)
    assert model.percent_at_rest(12.06) == pytest.approx(50.0, abs=0.1)


def test_custom_curve() -> None:
    model = BatteryModel(cells=2, curve=[(3.0, 0.0), (4.0, 100.0)], warmup=0.0, min_readings=1)
    assert model.update(7.0, now=0.0) == pytest.approx(50.0)


# --- validation -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        pytest.param({"chemistry": "nicd"}, "chemistry must be one of", id="chemistry"),
        pytest.param({"cells": 0}, "cells", id="cells-zero"),
        pytest.param({"cells": 2.5}, "cells must be an integer", id="cells-float"),
        pytest.param({"capacity_ah": 0.0}, "capacity_ah", id="capacity-zero"),
        pytest.param({"capacity_ah": math.nan}, "capacity_ah", id="capacity-nan"),
        pytest.param({"internal_resistance": -0.1}, "internal_resistance", id="resistance"),
        pytest.param({"smoothing": 0.0}, "smoothing", id="smoothing"),
        pytest.param({"warmup": -1.0}, "warmup", id="warmup"),
        pytest.param({"min_readings": 0}, "min_readings", id="min-readings"),
        pytest.param({"low": 120.0}, "low", id="low-range"),
        pytest.param({"low": 10.0, "critical": 20.0}, "critical must be <= low", id="order"),
        pytest.param({"hysteresis": -1.0}, "hysteresis", id="hysteresis"),
        pytest.param({"curve": [(3.0, 0.0)]}, "at least two", id="curve-short"),
        pytest.param({"curve": "3.0,0"}, "sequence of", id="curve-string"),
        pytest.param({"curve": 5}, "sequence of", id="curve-number"),
        pytest.param({"chemistry": 5}, "chemistry must be a string", id="chemistry-type"),
        pytest.param({"chemistry": ["li-ion"]}, "chemistry must be a string", id="chemistry-list"),
        pytest.param({"curve": [(3.0, 0.0), (2.9, 50.0)]}, "must rise", id="curve-falls"),
        pytest.param({"curve": [(3.0, 0.0), (3.1, 0.0)]}, "must rise", id="curve-flat"),
        pytest.param({"curve": [(3.0, 0.0), (3.1, 101.0)]}, "curve percent", id="curve-101"),
        pytest.param({"curve": [(3.0, 0.0), (3.1,)]}, "pairs", id="curve-point"),
    ],
)
def test_bad_options_raise_one_line_value_errors(kwargs: dict[str, object], match: str) -> None:
    # A value of the wrong type (cells=2.5) is a TypeError, as core.validation makes it.
    with pytest.raises((TypeError, ValueError), match=match) as info:
        BatteryModel(**kwargs)  # type: ignore[arg-type]
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("voltage", [math.nan, math.inf, -1.0, True])
def test_bad_readings_raise(voltage: float) -> None:
    with pytest.raises((TypeError, ValueError), match="voltage"):
        BatteryModel().update(voltage, now=0.0)
    with pytest.raises(ValueError, match="current"):
        BatteryModel().update(26.0, math.nan, now=0.0)


# --- warm-up, smoothing, clamping -------------------------------------------------------------


def test_none_until_warm_up_then_known() -> None:
    model = BatteryModel("li-ion", cells=7, warmup=3.0, min_readings=5)
    assert model.percentage is None
    seen = [model.update(26.74, now=t / 10) for t in range(31)]
    assert all(p is None for p in seen[:30])  # 0.0 .. 2.9 s
    assert seen[30] == pytest.approx(50.0)
    assert model.level is BatteryLevel.OK


def test_too_few_readings_stay_none_however_long() -> None:
    model = BatteryModel("li-ion", cells=7, warmup=1.0, min_readings=5)
    for t in (0.0, 10.0, 20.0, 30.0):
        assert model.update(26.74, now=t) is None
    assert model.update(26.74, now=40.0) == pytest.approx(50.0)


def test_loaded_readings_without_current_are_not_used() -> None:
    model = BatteryModel("li-ion", cells=7, warmup=0.5, min_readings=2)
    for t in range(50):
        assert model.update(24.0, now=t / 10, loaded=True) is None  # never a made-up number
    now = warm(model, 26.74)
    assert model.percentage == pytest.approx(50.0)
    model.update(24.0, now=now, loaded=True)  # a sag under load moves nothing
    assert model.percentage == pytest.approx(50.0)


def test_heavy_draw_before_resistance_is_known_is_not_used() -> None:
    model = BatteryModel("li-ion", cells=7, warmup=0.0, min_readings=1, rest_current=2.0)
    assert model.update(25.0, 30.0, now=0.0) is None
    assert model.update(26.74, 1.0, now=1.0) == pytest.approx(50.0)  # no step: R unknown
    assert model.internal_resistance is None


def test_smoothing_is_exponential_with_its_time_constant() -> None:
    model = BatteryModel("li-ion", cells=1, smoothing=30.0, warmup=0.0, min_readings=1)
    model.update(ocv(50.0, OCV_CURVES["li-ion"]), now=0.0)
    # A step to 60 %: after one time constant, 1 - 1/e of the way, whatever the rate.
    step = ocv(60.0, OCV_CURVES["li-ion"])
    for i in range(1, 301):
        model.update(step, now=i * 0.1)
    assert model.percentage == pytest.approx(50.0 + 10.0 * (1 - math.exp(-1)), abs=1e-6)
    coarse = BatteryModel("li-ion", cells=1, smoothing=30.0, warmup=0.0, min_readings=1)
    coarse.update(ocv(50.0, OCV_CURVES["li-ion"]), now=0.0)
    for i in range(1, 4):
        coarse.update(step, now=i * 10.0)
    assert coarse.percentage == pytest.approx(model.percentage, abs=1e-6)  # dt-aware


def test_clamped_to_0_and_100() -> None:
    model = BatteryModel("li-ion", cells=7)
    warm(model, 40.0)
    assert model.percentage == 100.0
    model = BatteryModel("li-ion", cells=7)
    warm(model, 5.0)
    assert model.percentage == 0.0


# --- sag compensation ---------------------------------------------------------------------------


def test_sag_is_undone_with_a_configured_resistance() -> None:
    model = BatteryModel("li-ion", cells=7, internal_resistance=0.05, warmup=0.0, min_readings=1)
    rest = 7 * 3.82
    assert model.update(rest - 20 * 0.05, 20.0, now=0.0) == pytest.approx(50.0)
    assert model.internal_resistance == 0.05


def test_resistance_is_estimated_from_current_steps() -> None:
    r, rest = 0.04, 7 * 3.82
    model = BatteryModel("li-ion", cells=7, warmup=0.0, min_readings=1)
    assert model.internal_resistance is None
    now = 0.0
    for i in range(40):
        current = 25.0 if i % 2 else 1.0  # steps of 24 A every 50 ms
        model.update(round(rest - current * r, 1), current, now=now)
        now += 0.05
    assert model.internal_resistance == pytest.approx(r, rel=0.15)
    assert model.update(round(rest - 25.0 * r, 1), 25.0, now=now) == pytest.approx(50.0, abs=2.0)


def test_charge_is_counted_with_a_capacity() -> None:
    # 1 Ah drawn at 36 A for 10 s is 10 %; the voltage (held at 50 %) corrects slowly.
    model = BatteryModel(
        "li-ion", cells=7, capacity_ah=1.0, internal_resistance=0.0, smoothing=1e6, warmup=0.0,
        min_readings=1,
    )  # fmt: skip
    rest = 7 * 3.82
    model.update(rest, 36.0, now=0.0)
    for i in range(1, 101):
        model.update(rest, 36.0, now=i * 0.1)
    assert model.percentage == pytest.approx(40.0, abs=0.01)


# --- levels and hysteresis ------------------------------------------------------------------------


def levels(model: BatteryModel, percents: list[float]) -> list[BatteryLevel | None]:
    curve, out = model.curve, []
    for i, p in enumerate(percents):
        model.update(ocv(p, curve) * model.cells, now=float(i))
        out.append(model.level)
    return out


def test_levels_with_hysteresis() -> None:
    model = BatteryModel("li-ion", cells=7, smoothing=1e-9, warmup=0.0, min_readings=1)
    L, C, OK = BatteryLevel.LOW, BatteryLevel.CRITICAL, BatteryLevel.OK
    got = levels(model, [30, 21, 19.5, 21, 24.9, 25.1, 19, 9.9, 12, 14.9, 15.1, 26])
    assert got == [OK, OK, L, L, L, OK, L, C, C, C, L, OK]


def test_level_is_none_before_warm_up() -> None:
    model = BatteryModel("li-ion", cells=7)
    model.update(20.0, now=0.0)
    assert model.level is None
    assert model.percentage is None


# --- properties ---------------------------------------------------------------------------------

volts = st.floats(min_value=0.0, max_value=60.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(CHEMISTRIES), st.integers(1, 16), volts, volts)
def test_monotonic_in_voltage_at_rest(chemistry: str, cells: int, a: float, b: float) -> None:
    low, high = sorted((a, b))
    pa, pb = (BatteryModel(chemistry, cells=cells) for _ in range(2))  # type: ignore[arg-type]
    warm(pa, low)
    warm(pb, high)
    assert pa.percentage is not None
    assert pb.percentage is not None
    assert pa.percentage <= pb.percentage


@settings(max_examples=200, deadline=None)
@given(
    st.sampled_from(CHEMISTRIES),
    st.lists(
        st.tuples(volts, st.none() | st.floats(-50, 200), st.floats(0.0, 5.0), st.booleans()),
        min_size=1,
        max_size=60,
    ),
    st.none() | st.floats(0.01, 100.0),
)
def test_clamped_whatever_the_readings(
    chemistry: str, readings: list[tuple[float, float | None, float, bool]], capacity: float | None
) -> None:
    model = BatteryModel(chemistry, cells=4, capacity_ah=capacity)  # type: ignore[arg-type]
    now = 0.0
    for voltage, current, dt, loaded in readings:
        now += dt
        p = model.update(voltage, current, now=now, loaded=loaded)
        assert p is None or 0.0 <= p <= 100.0


@settings(max_examples=100, deadline=None)
@given(
    st.floats(0.5, 10.0),
    st.integers(1, 20),
    st.lists(st.tuples(volts, st.floats(0.0, 0.5)), min_size=1, max_size=80),
)
def test_none_before_warm_up(
    warmup: float, min_readings: int, readings: list[tuple[float, float]]
) -> None:
    model = BatteryModel("lifepo4", cells=8, warmup=warmup, min_readings=min_readings)
    now = 100.0
    for count, (voltage, dt) in enumerate(readings, 1):
        now += dt
        p = model.update(voltage, now=now)
        if count < min_readings or now - 100.0 - readings[0][1] < warmup:
            assert p is None


# --- the simulated pack ---------------------------------------------------------------------


def test_pack_model_is_opt_in_and_the_linear_battery_unchanged() -> None:
    fw = ChassisFirmware()
    assert fw.pack is None
    assert fw.battery_charge is None
    assert fw.battery_voltage == pytest.approx(
        fw.spec.battery_full - 0.03 * 4 * 0.3
    )  # idle draw sags


def test_pack_model_discharges_and_sags_under_acceleration() -> None:
    fw = ChassisFirmware(ChassisSpec(pack=PackSpec("li-ion", cells=7, capacity_ah=0.2)))
    enc = ChassisEncoder()
    fw.on_connect(0.0)
    rest = fw.battery_voltage
    assert rest == pytest.approx(7 * 4.2 - 1.2 * 0.03)
    now = 0.02
    fw.receive(enc.drive_velocity(1.0, 0.0), now)
    fw.poll(now)
    accelerating = fw.battery_voltage
    assert rest - accelerating > 0.5  # 24 A more through 0.03 ohm
    for _ in range(100):
        now += 0.02
        fw.receive(enc.drive_velocity(1.0, 0.0), now)
        fw.poll(now)
    assert fw.pack is not None
    charge = fw.battery_charge
    assert charge is not None
    assert charge == pytest.approx(100.0 - fw.pack.drawn_ah / 0.2 * 100.0)
    assert charge < 99.0
    assert rest - fw.battery_voltage > 0.3  # cruising still sags; and it has drained
    assert round(fw.telemetry().voltage, 1) == fw.telemetry().voltage  # 0.1 V, as the wire


def test_pack_spec_validation() -> None:
    with pytest.raises(ValueError, match="capacity_ah"):
        PackSpec(capacity_ah=0.0)
    with pytest.raises(ValueError, match="chemistry"):
        PackSpec("nimh")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="charge"):
        PackSpec(charge=101.0)


def test_device_refuses_a_battery_that_is_not_a_model() -> None:
    with pytest.raises(TypeError, match="BatteryModel"):
        Chassis("/dev/null", battery=20.0)  # type: ignore[arg-type]
    assert Chassis("/dev/null").battery_percentage is None


# --- through a real pty: the estimate against the pack's true charge ------------------------------


#: The driving pattern, a cycle of (seconds, linear m/s, angular rad/s): hard starts and
#: stops at the simulator's 1.5 m/s², cruising, a turn, a rest.
CYCLE = ((0.9, 1.0, 0.0), (0.6, 0.0, 0.0), (0.8, 0.6, 1.2), (0.4, 0.0, 0.0), (0.5, -0.8, 0.0))
REST = 3.5  #: seconds at rest first: the warm-up


def command_at(elapsed: float) -> tuple[float, float]:
    if elapsed < REST:
        return (0.0, 0.0)
    t = (elapsed - REST) % sum(step[0] for step in CYCLE)
    for seconds, linear, angular in CYCLE:
        if t < seconds:
            return (linear, angular)
        t -= seconds
    return (0.0, 0.0)


async def discharge(
    pack: PackSpec, model: BatteryModel, *, power: bool, until: float = 4.0, limit: float = 40.0
) -> tuple[list[float], list[RobotEvent], float | None]:
    """Drive the pattern until the true charge is below ``until`` percent: the errors
    (estimate - truth, percentage points) once known, the battery events, and when the
    estimate became known (s)."""
    errors: list[float] = []
    events: list[RobotEvent] = []
    known: float | None = None
    # The pack is driven flat on purpose: its critical level must not stop the drive.
    lets_it_drain = SafetyPolicy(battery=Reflex("ignore"), allow_unsafe=True)
    async with (
        ChassisSimulator(ChassisSpec(pack=pack)) as sim,
        Chassis(sim.port, battery=model, safety=lets_it_drain) as robot,
        anyio.create_task_group() as tg,
    ):

        async def watch() -> None:
            async for event in robot.events():
                if event.kind.value.startswith("battery"):
                    events.append(event)

        tg.start_soon(watch)
        if power:
            await robot.enable_power_telemetry()
        start = time.monotonic()
        async for _ in robot.telemetry():
            elapsed = time.monotonic() - start
            linear, angular = command_at(elapsed)
            if linear or angular:
                await robot.set_velocity(linear, angular)
            elif robot.commanded_velocity is not None:
                await robot.stop()
            truth = sim.firmware.battery_charge
            assert truth is not None
            estimate = robot.battery_percentage
            if estimate is not None:
                known = elapsed if known is None else known
                errors.append(estimate - truth)
            if truth < until or elapsed > limit:
                break
        await robot.stop()
        await anyio.sleep(0.1)  # room for a late duplicate event
        tg.cancel_scope.cancel()
    return errors, events, known


def summary(name: str, errors: list[float], known: float | None) -> tuple[float, float]:
    worst = max(abs(e) for e in errors)
    mean = sum(abs(e) for e in errors) / len(errors)
    print(
        f"\n{name}: known after {known:.2f} s; |error| max {worst:.2f} pp, mean {mean:.2f} pp, "
        f"bias {sum(errors) / len(errors):+.2f} pp over {len(errors)} readings"
    )
    return worst, mean


def check_events(events: list[RobotEvent], model: BatteryModel) -> None:
    kinds = [e.kind for e in events]
    assert kinds == [EventKind.BATTERY_LOW, EventKind.BATTERY_CRITICAL], events
    low, critical = events
    assert low.percentage is not None
    assert low.percentage < model.low
    assert critical.percentage is not None
    assert critical.percentage < model.critical
    assert low.voltage is not None


@pytest.mark.integration
@pytest.mark.slow
async def test_estimate_follows_the_simulated_pack_with_power_telemetry_and_capacity() -> None:
    # A 7S Li-ion pack of 0.12 Ah: the ~18 A of the pattern empties it in half a minute
    # (time compressed about a hundredfold from a real pack), 80 % to 4 %. The model is
    # told a capacity 10 % too large (a nameplate, not a measurement): the voltage,
    # its sag undone, corrects the count.
    pack = PackSpec("li-ion", cells=7, capacity_ah=0.12, internal_resistance=0.03, charge=80.0)
    model = BatteryModel("li-ion", cells=7, capacity_ah=0.132, smoothing=5.0)
    errors, events, known = await discharge(pack, model, power=True)
    worst, mean = summary("li-ion 7S, 0xB1 currents, capacity +10 %, R estimated", errors, known)
    assert known is not None
    assert known < REST  # known during the rest that starts the run
    assert model.internal_resistance == pytest.approx(0.03, rel=0.3)
    assert worst <= 5.0
    assert mean <= 3.0
    check_events(events, model)


@pytest.mark.integration
@pytest.mark.slow
async def test_estimate_from_voltage_alone_with_power_telemetry() -> None:
    # No capacity: the voltage (sag undone with the 0xB1 currents) is all there is;
    # the smoothing's lag behind a pack draining ~3 %/s is the larger part of the error.
    pack = PackSpec("li-ion", cells=7, capacity_ah=0.12, internal_resistance=0.03, charge=80.0)
    model = BatteryModel("li-ion", cells=7, smoothing=1.0)
    errors, events, known = await discharge(pack, model, power=True)
    worst, mean = summary("li-ion 7S, 0xB1 currents, no capacity", errors, known)
    assert worst <= 10.0
    assert mean <= 7.0
    check_events(events, model)


#: Bounds of the error with the pack's curve 30 mV per cell off the model's (measured:
#: see the test's printout and docs/battery.md).
CURVE_OFF_MAX = 12.0
CURVE_OFF_MEAN = 8.0


def shifted(curve: Sequence[tuple[float, float]], volts: float) -> list[tuple[float, float]]:
    """``curve`` with every point ``volts`` per cell higher: a real pack's cells are not
    the data sheet's."""
    return [(v + volts, p) for v, p in curve]


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.parametrize("offset", [-0.03, 0.03], ids=["30mV-low", "30mV-high"])
async def test_estimate_with_the_packs_curve_off_the_models(offset: float) -> None:
    # The pack's own curve is 30 mV per cell off the model's Li-ion curve (the figures
    # above use the same curve on both sides, so they cannot show a curve's error).
    # With the capacity known, the charge counted between readings carries it.
    curve = shifted(OCV_CURVES["li-ion"], offset)
    pack = PackSpec("li-ion", cells=7, capacity_ah=0.12, internal_resistance=0.03, charge=80.0,
                    curve=curve)  # fmt: skip
    model = BatteryModel("li-ion", cells=7, capacity_ah=0.12, smoothing=5.0)
    errors, _, known = await discharge(pack, model, power=True)
    worst, mean = summary(
        f"li-ion 7S, pack curve {offset * 1000:+.0f} mV/cell, capacity", errors, known
    )
    assert worst <= CURVE_OFF_MAX
    assert mean <= CURVE_OFF_MEAN


# --- where it shows: monitor ----------------------------------------------------------------------


class Captured:
    """What the command printed so far (``capsys``, read as it comes)."""

    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self._capsys = capsys
        self.text = ""

    def has(self, *patterns: str) -> bool:
        self.text += self._capsys.readouterr().out
        return all(re.search(p, self.text, re.MULTILINE) for p in patterns)

    @property
    def lines(self) -> list[str]:
        return self.text.splitlines()


async def monitored(
    capsys: pytest.CaptureFixture[str],
    device: str,
    port: str,
    *patterns: str,
    as_json: bool,
    **options: Any,
) -> Captured:
    """Run ``chassis-sdk monitor``'s coroutine on ``port`` with ``options`` until its
    output matches every one of ``patterns``; what it printed."""
    captured = Captured(capsys)
    async with anyio.create_task_group() as tg:
        tg.start_soon(
            functools.partial(monitor, profile(device), port, 115200, None, as_json, **options)
        )
        try:
            await until(lambda: captured.has(*patterns), timeout=15.0)
        except TimeoutError:
            raise AssertionError(f"no {patterns} in:\n{captured.text}") from None
        tg.cancel_scope.cancel()
    captured.has("")
    return captured


@pytest.mark.integration
async def test_monitor_shows_the_percentage_beside_the_voltage_and_the_level(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # A pack at 15 %: "--" while the model warms up (1 s), then the charge and LOW.
    pack = PackSpec("li-ion", cells=7, charge=15.0)
    model = BatteryModel("li-ion", cells=7, warmup=1.0, min_readings=3)
    async with ChassisSimulator(ChassisSpec(pack=pack)) as sim:
        got = await monitored(capsys, "chassis", sim.port, r"% LOW", "^event: battery low",
                              as_json=False, battery=model)  # fmt: skip
        truth = sim.firmware.battery_charge
    telemetry = [line for line in got.lines if line.startswith("  v=")]
    assert re.search(r" \d+\.\d V  --  docking=", telemetry[0]), telemetry[0]
    shown = [line for line in telemetry if "% LOW" in line]
    assert shown, got.text
    match = re.search(r" (\d+\.\d) V  (\d+) % LOW  docking=", shown[-1])
    assert match is not None, shown[-1]
    assert truth is not None
    assert abs(int(match[2]) - truth) <= 3  # the estimate against the pack's charge
    assert abs(float(match[1]) - 7 * ocv(truth, OCV_CURVES["li-ion"])) <= 0.2
    event = next(line for line in got.lines if line.startswith("event: battery low"))
    assert re.fullmatch(r"event: battery low: \d+\.\d V, \d+ %", event), event


@pytest.mark.integration
async def test_monitor_json_carries_the_percentage_once_known_and_the_events(
    capsys: pytest.CaptureFixture[str],
) -> None:
    pack = PackSpec("li-ion", cells=7, charge=5.0)
    model = BatteryModel("li-ion", cells=7, warmup=1.0, min_readings=3)
    async with ChassisSimulator(ChassisSpec(pack=pack)) as sim:
        got = await monitored(capsys, "chassis", sim.port, r'"kind": "BATTERY_CRITICAL"',
                              as_json=True, battery=model, read_only=True)  # fmt: skip
        truth = sim.firmware.battery_charge
    rows = [json.loads(line) for line in got.lines]
    frames = [r for r in rows if r["type"] == "Telemetry"]
    # Not known yet: left out, never null (nor a made-up number).
    assert "battery_percentage" not in frames[0]
    assert "battery_level" not in frames[0]
    known = [r for r in frames if "battery_percentage" in r]
    assert known, frames[-1]
    assert truth is not None
    assert abs(known[-1]["battery_percentage"] - truth) <= 3
    assert known[-1]["battery_level"] == "CRITICAL"
    events = [r for r in rows if r["type"] == "event"]
    assert [e["kind"] for e in events] == ["BATTERY_LOW", "BATTERY_CRITICAL"]
    assert all(e["percentage"] < model.critical for e in events)


@pytest.mark.integration
async def test_monitor_without_a_model_shows_the_voltage_alone(
    capsys: pytest.CaptureFixture[str],
) -> None:
    async with ChassisSimulator(ChassisSpec(pack=PackSpec("li-ion", cells=7))) as sim:
        text = await monitored(capsys, "chassis", sim.port, r"(  v=.*\n){3}", as_json=False)
        rows = await monitored(capsys, "chassis", sim.port, r'(.*"Telemetry".*\n){3}', as_json=True)
    frame = next(line for line in text.lines if line.startswith("  v="))
    assert re.search(r" \d+\.\d V  docking=", frame), frame
    first = next(r for r in map(json.loads, rows.lines) if r["type"] == "Telemetry")
    assert "battery_percentage" not in first
    assert "battery_level" not in first


@pytest.mark.integration
async def test_monitor_of_a_board_shows_the_percentage_of_its_battery_stream(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The board reports its battery once a second: "--" for the first ones, known from
    # the third (min_readings=3), LOW at 15 %.
    pack = PackSpec("li-ion", cells=7, charge=15.0)
    model = BatteryModel("li-ion", cells=7, warmup=1.5, min_readings=3)
    async with BoardSimulator(BoardSpec(pack=pack)) as sim:
        got = await monitored(capsys, "board", sim.port, r"^event: battery low", r"% LOW$",
                              as_json=False, battery=model)  # fmt: skip
        truth = sim.firmware.battery_charge
    # Its own view or the generic one's battery line: the charge beside the voltage.
    battery = [line for line in got.lines if re.search(r"\d+\.\d V  ", line)]
    assert re.search(r"\d+\.\d V  --$", battery[0]), battery
    match = re.search(r"\d+\.\d V  (\d+) % LOW$", battery[-1])
    assert match is not None, battery
    assert "monotonic=" not in got.text  # no clock fields in a line
    assert truth is not None
    assert abs(int(match[1]) - truth) <= 3


# --- where it shows: a Foxglove/MCAP recording -----------------------------------------------------


@pytest.mark.integration
async def test_an_mcap_recording_carries_the_charge_beside_the_voltage(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from chassis_sdk.recording import McapRecording

    pack = PackSpec("li-ion", cells=7, charge=5.0)
    model = BatteryModel("li-ion", cells=7, warmup=0.5, min_readings=3)
    path = tmp_path / "run.mcap"
    async with (
        ChassisSimulator(ChassisSpec(pack=pack)) as sim,
        Chassis(sim.port, battery=model) as robot,
    ):
        recording = McapRecording(path, robot)
        try:
            async for event in robot.events():
                if event.kind is EventKind.BATTERY_CRITICAL:
                    break
            await anext(robot.telemetry())  # one frame recorded after it
            await anext(robot.telemetry())
        finally:
            recording.close()
        truth = sim.firmware.battery_charge
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channel = next(c for c in summary.channels.values() if c.topic == "/chassis/telemetry")
        schema = json.loads(summary.schemas[channel.schema_id].data)
        assert {"voltage", "battery_percentage", "battery_level"} <= set(schema["properties"])
        frames = [
            json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/chassis/telemetry"])
        ]
    with path.open("rb") as f:
        logs = [
            proto_fields(m.data)
            for _, _, m in make_reader(f).iter_messages(topics=["/chassis/log"])
        ]
    assert "battery_percentage" not in frames[0]  # not known yet: left out
    assert frames[-1]["battery_level"] == "CRITICAL"
    assert truth is not None
    assert abs(frames[-1]["battery_percentage"] - truth) <= 3
    # foxglove.Log: 2 level (WARNING = 3), 3 message.
    critical = [entry for entry in logs if b"battery critical" in entry[3]]
    assert len(critical) == 1, logs
    assert critical[0][2] == 3


def proto_fields(data: bytes) -> dict[int, Any]:
    """The top-level fields of a protobuf message (varints and length-delimited only,
    what foxglove.Log holds), by number."""
    fields: dict[int, Any] = {}
    i = 0

    def varint() -> int:
        nonlocal i
        value = shift = 0
        while True:
            byte = data[i]
            i += 1
            value |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                return value

    while i < len(data):
        key = varint()
        number, wire = key >> 3, key & 7
        if wire == 0:
            fields[number] = varint()
        elif wire == 2:
            size = varint()
            fields[number] = data[i : i + size]
            i += size
        else:
            raise AssertionError(f"wire type {wire} in {data!r}")
    return fields


@pytest.mark.integration
async def test_the_monitor_command_takes_the_model_from_the_profile(tmp_path: Path) -> None:
    # The whole command in a subprocess: the profile's [battery] table is the model.
    profile_file = tmp_path / "chassis-sdk.toml"
    profile_file.write_text(
        '[battery]\nchemistry = "li-ion"\ncells = 7\nwarmup = 0.5\nmin_readings = 3\n'
    )
    async with ChassisSimulator(ChassisSpec(pack=PackSpec("li-ion", cells=7, charge=15.0))) as sim:
        code, out, err = await cli(
            "monitor",
            sim.port,
            "--seconds",
            "2",
            "--json",
            env={"CHASSIS_SDK_CONFIG": str(profile_file)},
        )
        truth = sim.firmware.battery_charge
    assert code == 0, err
    frames = [r for r in map(json.loads, out.splitlines()) if r["type"] == "Telemetry"]
    assert "battery_percentage" not in frames[0]  # not known yet: left out
    assert frames[-1]["battery_level"] == "LOW"
    assert truth is not None
    assert abs(frames[-1]["battery_percentage"] - truth) <= 3


def test_the_pack_voltage_of_0xb1_ignores_a_driver_that_reads_nothing() -> None:
    from chassis_sdk.devices.chassis.device import _pack_voltage
    from chassis_sdk.protocol import PowerTelemetry, WheelCurrents

    currents = WheelCurrents(0.0, 0.0, 0.0, 0.0)
    assert _pack_voltage(PowerTelemetry(currents, 25.6, 25.4)) == pytest.approx(25.5)
    assert _pack_voltage(PowerTelemetry(currents, 0.0, 25.6)) == 25.6  # front driver offline
    assert _pack_voltage(PowerTelemetry(currents, 25.6, 3.0)) == 25.6
