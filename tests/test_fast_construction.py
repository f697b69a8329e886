"""The fast constructors of hot messages give exactly what the normal ones give."""

from __future__ import annotations

import dataclasses
import datetime
import enum
import json
from typing import Any

import pytest

from chassis_sdk.core.construct import MemberCache, frozen_builder
from chassis_sdk.protocol import (
    ChassisStatus,
    DockingState,
    ImuSample,
    Telemetry,
    Vector3,
    WheelSpeeds,
)


def test_builder_equals_the_dataclass_constructor_and_stays_frozen() -> None:
    args = (24.6, ChassisStatus.REMOTE_OFFLINE, DockingState.DOCKED, 0.3, -0.2,
            WheelSpeeds(0.1, 0.2, 0.3, 0.4), 7, 1.5)  # fmt: skip
    built = frozen_builder(Telemetry)(*args)
    assert built == Telemetry(*args)
    assert hash(built) == hash(Telemetry(*args))
    assert repr(built) == repr(Telemetry(*args))
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.voltage = 1.0  # type: ignore[misc]
    # Every field positionally, the raw counts (not compared) included.
    imu = frozen_builder(ImuSample)(Vector3(1, 2, 3), Vector3(4, 5, 6), Vector3(7, 8, 9), 0.5, None)
    assert imu == ImuSample(Vector3(1, 2, 3), Vector3(4, 5, 6), Vector3(7, 8, 9), 0.5)


def test_builder_rejects_classes_it_cannot_fill() -> None:
    @dataclasses.dataclass(frozen=True)
    class NoSlots:
        x: int

    with pytest.raises(TypeError, match="slotted dataclass"):
        frozen_builder(NoSlots)


def test_member_cache_returns_members_and_stays_bounded() -> None:
    cache = MemberCache(ChassisStatus, limit=4)
    for value in range(10):
        assert cache[value] is ChassisStatus(value) or cache[value] == ChassisStatus(value)
        assert type(cache[value]) is ChassisStatus
    assert len(cache) == 4
    docking = MemberCache(DockingState)
    assert docking[4] is DockingState.DOCKED
    assert docking[9].name == "UNKNOWN_9"  # unknown values decode, as without the cache


def test_byte_sum_is_the_plain_byte_sum_for_any_frame_size() -> None:
    import random

    from chassis_sdk.core.framing import byte_sum

    rng = random.Random(5)
    for size in (0, 1, 24, 250, 255, 256):
        for data in (b"\xff" * size, rng.randbytes(size)):
            assert byte_sum(data, 0) & 0xFFFF == sum(data)


# --- printing and plain data --------------------------------------------------------------


def _standard_repr(value: object) -> str:
    """The text the standard library's ``repr`` gives, worked out without calling any
    ``__repr__`` this package defines: dataclasses' format, ``NamedTuple``'s, enum's."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        shown = [f for f in dataclasses.fields(value) if f.repr]
        inner = ", ".join(f"{f.name}={_standard_repr(getattr(value, f.name))}" for f in shown)
        return f"{type(value).__qualname__}({inner})"
    if isinstance(value, tuple) and hasattr(value, "_fields"):
        inner = ", ".join(
            f"{n}={_standard_repr(v)}" for n, v in zip(value._fields, value, strict=True)
        )
        return f"{type(value).__name__}({inner})"
    if isinstance(value, enum.Enum):
        stdlib = next(c for c in type(value).__mro__ if c.__module__ == "enum")
        standard: Any = stdlib.__repr__
        return str(standard(value))
    return repr(value)


def _messages() -> list[object]:
    from chassis_sdk.devices import profiles
    from chassis_sdk.protocol import (
        DriverError,
        DriverStatus,
        MotorStatus,
        WheelDriver,
    )

    found = [
        msg
        for p in profiles().values()
        for _, msg in (*p.codec.examples, *p.codec.command_examples)
    ]
    both = ChassisStatus.HARDWARE_ESTOP | ChassisStatus.FRONT_BUMPER
    unknown_bit = ChassisStatus(1 << 14)
    driver = WheelDriver(DriverError(0), MotorStatus(3), -1.5, 2.0)
    found += [
        Telemetry(24.6, both, DockingState(9), 0.3, -0.2, WheelSpeeds(0.1, 0.2, 0.3, 0.4)),
        Telemetry(1e-7, unknown_bit, DockingState.DOCKED, -0.0, 1e22, WheelSpeeds(1, 2, 3, 4)),
        DriverStatus(driver, driver, driver, driver, 20.5, 21.0, 24.0, 23.9),
        ImuSample(Vector3(1, 2, 3), Vector3(4, 5, 6), Vector3(7, 8, 9), 0.5, None),
        Telemetry(24.6, ChassisStatus(0), DockingState.DOCKED, 0.3, -0.2, WheelSpeeds(0, 0, 0, 0)),
    ]
    return found


def test_message_reprs_are_the_standard_text() -> None:
    messages = _messages()
    assert len({type(m) for m in messages}) >= 20  # every kind both devices send or get
    for msg in messages:
        assert repr(msg) == _standard_repr(msg), type(msg).__name__
        assert str(msg) == repr(msg)


def test_enum_reprs_are_kept_once_and_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    from chassis_sdk.core import enums

    monkeypatch.setattr(enums, "_reprs", {})
    monkeypatch.setattr(enums, "_REPRS_KEPT", 3)
    values = [ChassisStatus(v) for v in (0, 8, 9, 1 << 14, 8)] + [DockingState(2)]
    for value in values:
        assert repr(value) == _standard_repr(value)
    assert len(enums._reprs) == 3  # 0, 8, 9 kept; the rest made each time
    assert repr(ChassisStatus(8)) is repr(ChassisStatus(8))  # kept, not rebuilt


def test_fast_repr_refuses_other_classes() -> None:
    from chassis_sdk.core.construct import fast_repr

    with pytest.raises(TypeError, match="neither a dataclass nor a NamedTuple"):
        fast_repr(int)


def _standard_plain(value: object) -> object:
    """What :func:`~chassis_sdk.core.plain.plain` promises, written the obvious way:
    objects without their None fields, an enum's name, a flag's set bits by name."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
        return {k: _standard_plain(v) for k, v in fields.items() if v is not None}
    if isinstance(value, tuple) and hasattr(value, "_fields"):
        fields = dict(zip(value._fields, value, strict=True))
        return {k: _standard_plain(v) for k, v in fields.items() if v is not None}
    if isinstance(value, enum.Flag):
        bits = int(value.value)
        return "|".join(
            type(value)(1 << n).name or f"BIT_{n}"
            for n in range(bits.bit_length())
            if bits >> n & 1
        )
    if isinstance(value, enum.Enum):
        return value.name
    if isinstance(value, datetime.date):
        return value.isoformat()
    return value


def test_plain_data_is_what_it_promises() -> None:
    from chassis_sdk.core.plain import plain

    for msg in _messages():
        converted = plain(msg)
        assert converted == _standard_plain(msg), type(msg).__name__
        assert json.loads(json.dumps(converted)) == converted
        # Enums and flags become names, never stay enum members or numbers, and a
        # None is left out, never null.
        assert not any(isinstance(v, enum.Enum) for v in _leaves(converted))
        assert None not in _leaves(converted)


def _leaves(value: object) -> list[object]:
    if isinstance(value, dict):
        return [leaf for v in value.values() for leaf in _leaves(v)]
    return [value]
