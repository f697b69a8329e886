"""``Notifier``: the one way recorders and bridges watch a device (its raw traffic, its
named streams, its connection states), and everything it adds goes with close()."""

from __future__ import annotations

import gc
import weakref

import pytest

from chassis_sdk import Chassis, ConnectionState, Telemetry
from chassis_sdk.core.notifier import Notifier
from chassis_sdk.devices.chassis.firmware import ChassisFirmware
from chassis_sdk.sim import ChassisSimulator


def _telemetry_bytes() -> bytes:
    firmware = ChassisFirmware()
    firmware.on_connect(0.0)
    return firmware.poll(0.0)


class Recorder:
    """A tap that keeps what it saw."""

    def __init__(self) -> None:
        self.received: list[bytes] = []
        self.sent: list[bytes] = []

    def rx(self, data: bytes, now: float) -> None:
        self.received.append(data)

    def tx(self, data: bytes, now: float) -> None:
        self.sent.append(data)


def test_taps_and_listeners_see_fed_bytes_and_go_with_close() -> None:
    robot = Chassis("/dev/never-opened")
    frame = _telemetry_bytes()
    notifier = Notifier(robot)
    assert {"telemetry", "odometry", "events"} <= set(notifier.stream_names)
    first, second = Recorder(), Recorder()
    seen: list[object] = []
    notifier.add_tap(first)
    notifier.add_tap(second)
    notifier.listen("telemetry", seen.append)
    gc.collect()  # the notifier holds its listeners: nothing is lost to the collector
    robot.feed(frame, 1.0)
    assert first.received == second.received == [frame]
    assert len(seen) == 1
    assert isinstance(seen[0], Telemetry)
    notifier.close()
    notifier.close()  # again: nothing to remove
    robot.feed(frame, 2.0)
    assert first.received == [frame]
    assert len(seen) == 1


def test_an_unknown_stream_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="chassis has no stream 'imu'; it has: .*telemetry"):
        Notifier(Chassis("/dev/never-opened")).listen("imu", print)


@pytest.mark.integration
async def test_it_sees_both_directions_and_the_states_of_a_real_link() -> None:
    states: list[ConnectionState] = []
    tap = Recorder()
    async with ChassisSimulator() as sim:
        robot = Chassis(sim.port)
        with Notifier(robot) as notifier:
            notifier.add_tap(tap)
            notifier.listen_states(states.append)
            async with robot:
                await robot.get_firmware_version()
        assert ConnectionState.CONNECTED in states
        assert states[-1] is ConnectionState.DISCONNECTED
        assert any(frame[4] == 0x07 for frame in tap.sent)  # the 0x07 request, as written
        assert any(b"\xed\xde" in chunk for chunk in tap.received)


def test_a_notifier_nobody_keeps_goes_on_until_closed() -> None:
    robot = Chassis("/dev/never-opened")
    seen: list[object] = []
    notifier = Notifier(robot)
    notifier.listen("telemetry", seen.append)
    kept = weakref.ref(notifier)
    del notifier  # no reference kept but the device's
    gc.collect()
    robot.feed(_telemetry_bytes(), 1.0)
    assert len(seen) == 1
    alive = kept()
    assert alive is not None
    alive.close()
    robot.feed(_telemetry_bytes(), 2.0)
    assert len(seen) == 1


def test_a_listener_that_raises_does_not_starve_the_others(
    caplog: pytest.LogCaptureFixture,
) -> None:
    robot = Chassis("/dev/never-opened")
    seen: list[object] = []
    calls = 0

    def broken(message: object) -> None:
        nonlocal calls
        calls += 1
        raise OSError("disk full")

    with Notifier(robot) as notifier:
        bad = notifier.listen("telemetry", broken)
        notifier.listen("telemetry", seen.append)
        robot.feed(_telemetry_bytes(), 1.0)
        robot.feed(_telemetry_bytes(), 2.0)
    assert len(seen) == 2
    assert calls == 1  # removed at its first error
    assert isinstance(bad.error, OSError)
    assert "listener test_a_listener_that_raises" in caplog.text
    assert "on 'telemetry' raised OSError and was removed" in caplog.text
    assert caplog.text.count("OSError: disk full") == 1  # logged once, with its traceback


def test_a_device_class_with_the_old_kind_is_refused() -> None:
    class Mower(Chassis):
        kind = "mower"

    with pytest.raises(TypeError, match="`kind` is now `device_name`"):
        Mower("/dev/never-opened")


@pytest.mark.integration
async def test_a_simulator_keeps_its_counts_after_it_stops() -> None:
    async with ChassisSimulator() as sim:
        async with Chassis(sim.port) as robot:
            await robot.get_firmware_version()
        sent = sim.bytes_sent
    assert sent > 0
    assert sim.bytes_sent == sent
