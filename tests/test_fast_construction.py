"""The fast constructors of hot messages give exactly what the normal ones give."""

from __future__ import annotations

import dataclasses

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
