"""Events (each kind produced by the simulators' fault injection, once per edge),
wait_for, wait_connected and the confirm= variants (a timeout is an SDK error), and what
a device reports of itself: diagnose() and motion_blocked()."""

from __future__ import annotations

import asyncio

import pytest

from chassis_sdk import (
    Board,
    Chassis,
    ChassisError,
    ChassisStatus,
    ConnectionState,
    DockingState,
    DriverError,
    EventKind,
    RequestTimeoutError,
    RobotEvent,
)
from chassis_sdk.sim import BoardSimulator, ChassisSimulator, ChassisSpec

E = EventKind


class Recorder:
    """Collects every event of a device in a background task; ``expect`` walks them in
    order with a cursor, so each expected edge is matched by a distinct event."""

    def __init__(self, robot: Chassis | Board) -> None:
        self.events: list[RobotEvent] = []
        self._cursor = 0
        self._sub = robot.events()
        self._changed = asyncio.Event()
        self._task = asyncio.ensure_future(self._run())

    async def _run(self) -> None:
        async for event in self._sub:
            self.events.append(event)
            self._changed.set()

    async def expect(self, kind: EventKind, source: str = "", timeout: float = 3.0) -> RobotEvent:
        """Wait for the next event of this kind and source after the cursor."""
        async with asyncio.timeout(timeout):
            while True:
                for i in range(self._cursor, len(self.events)):
                    event = self.events[i]
                    if event.kind is kind and event.source == source:
                        self._cursor = i + 1
                        return event
                self._changed.clear()
                await self._changed.wait()

    def pairs(self) -> list[tuple[EventKind, str]]:
        return [(e.kind, e.source) for e in self.events]

    def close(self) -> None:
        self._task.cancel()


async def frames(robot: Chassis, n: int) -> None:
    """Let ``n`` telemetry frames go by (room for a duplicate event to show up)."""
    async with robot.telemetry() as sub:
        for _ in range(n):
            await anext(sub)


@pytest.mark.integration
async def test_every_chassis_event_kind_once_per_edge() -> None:
    spec = ChassisSpec(docking_step=0.05)
    async with (
        ChassisSimulator(spec) as sim,
        Chassis(sim.port, battery_low=24.0, link_timeout=0.15, reconnect=True) as robot,
    ):
        rec = Recorder(robot)
        fw = sim.firmware
        await frames(robot, 2)
        fw.set_hardware_estop(True)
        await rec.expect(E.ESTOP_ENGAGED, "hardware")
        fw.set_hardware_estop(False)
        await rec.expect(E.ESTOP_RELEASED, "hardware")
        fw.set_remote_estop(True)
        await rec.expect(E.ESTOP_ENGAGED, "remote")
        fw.set_remote_estop(False)
        await rec.expect(E.ESTOP_RELEASED, "remote")
        await robot.emergency_stop(confirm=True)
        await rec.expect(E.ESTOP_ENGAGED, "software")
        await robot.release_emergency_stop(confirm=True)
        await rec.expect(E.ESTOP_RELEASED, "software")
        fw.press_bumper(front=True)
        await rec.expect(E.BUMPER_HIT, "front")
        fw.press_bumper(front=False)
        await rec.expect(E.BUMPER_HIT, "rear")
        fw.set_driver_offline(front=True)
        await rec.expect(E.DRIVER_OFFLINE, "front")
        fw.set_driver_offline(front=True, offline=False)
        await rec.expect(E.DRIVER_ONLINE, "front")
        fw.set_driver_fault(3, DriverError.OVER_CURRENT)
        await rec.expect(E.DRIVER_ERROR, "rear_right")
        await robot.clear_faults(confirm=True)
        await rec.expect(E.BUMPER_CLEARED, "front")
        await rec.expect(E.BUMPER_CLEARED, "rear")
        await rec.expect(E.DRIVER_ERROR_CLEARED, "rear_right")
        await robot.start_docking(confirm=True)
        docked = await rec.expect(E.DOCKING_CHANGED)
        assert docked.docking is DockingState.CENTER_FOUND
        await robot.wait_for(lambda t: t.docking is DockingState.DOCKED, 3.0)
        await robot.stop_docking(confirm=True)
        fw.set_battery(23.5)
        low = await rec.expect(E.BATTERY_LOW)
        assert low.voltage is not None
        assert low.voltage < 24.0
        fw.set_battery(25.0)
        await rec.expect(E.BATTERY_OK)
        sim.reset_firmware(downtime=0.4)
        await rec.expect(E.LINK_STALE)
        await rec.expect(E.LINK_RESTORED)
        sim.unplug()
        await rec.expect(E.LINK_LOST)
        await sim.replug()
        await rec.expect(E.LINK_RESTORED)
        await frames(robot, 10)  # room for any duplicate to show
        rec.close()
    docking = [e.docking for e in rec.events if e.kind is E.DOCKING_CHANGED]
    # ... and the reset's power-up state, reported after the link came back.
    assert docking == [
        DockingState.CENTER_FOUND, DockingState.CONTACT, DockingState.DOCKED, DockingState.EXITED,
        DockingState.SEARCHING,
    ]  # fmt: skip
    assert rec.pairs() == [
        (E.ESTOP_ENGAGED, "hardware"), (E.ESTOP_RELEASED, "hardware"),
        (E.ESTOP_ENGAGED, "remote"), (E.ESTOP_RELEASED, "remote"),
        (E.ESTOP_ENGAGED, "software"), (E.ESTOP_RELEASED, "software"),
        # each hit, then what the reflex did about it (stop, the default)
        (E.BUMPER_HIT, "front"), (E.REFLEX, "front_bumper"),
        (E.BUMPER_HIT, "rear"), (E.REFLEX, "rear_bumper"),
        (E.DRIVER_OFFLINE, "front"), (E.DRIVER_ONLINE, "front"),
        (E.DRIVER_ERROR, "rear_right"),
        (E.BUMPER_CLEARED, "front"), (E.BUMPER_CLEARED, "rear"),
        (E.DRIVER_ERROR_CLEARED, "rear_right"),
        *[(E.DOCKING_CHANGED, "")] * 4,
        (E.BATTERY_LOW, ""), (E.BATTERY_OK, ""),
        (E.LINK_STALE, ""), (E.LINK_RESTORED, ""), (E.DOCKING_CHANGED, ""),
        (E.LINK_LOST, ""), (E.LINK_RESTORED, ""),
    ]  # fmt: skip
    assert str(rec.events[0]) == "estop engaged (hardware)"


@pytest.mark.integration
async def test_board_battery_and_link_events() -> None:
    async with (
        BoardSimulator() as sim,
        Board(sim.port, battery_low=11.5, link_timeout=0.15) as board,
    ):
        rec = Recorder(board)
        sim.firmware.set_battery(11.0)
        event = await rec.expect(E.BATTERY_LOW)  # 0x13 comes at 1 Hz
        assert str(event).startswith("battery low: 1")
        sim.reset_firmware(downtime=0.3)
        await rec.expect(E.LINK_STALE)
        await rec.expect(E.LINK_RESTORED)
        rec.close()
    assert rec.pairs() == [(E.BATTERY_LOW, ""), (E.LINK_STALE, ""), (E.LINK_RESTORED, "")]


def test_bad_battery_threshold() -> None:
    with pytest.raises(ValueError, match="battery_low"):
        Chassis("/dev/null", battery_low=-1.0)


# --- wait_for and confirm ------------------------------------------------------------------------


@pytest.mark.integration
async def test_wait_for_returns_the_latest_at_once_and_times_out_otherwise() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        first = await anext(robot.telemetry())
        t = await robot.wait_for(lambda t: ChassisStatus.REMOTE_OFFLINE in t.status, 1.0)
        assert t.seq >= first.seq
        with pytest.raises(TimeoutError, match="no telemetry satisfied"):
            await robot.wait_for(lambda t: t.voltage > 100, 0.1)
        with pytest.raises(ValueError, match="timeout"):
            await robot.wait_for(lambda t: True, float("inf"))


@pytest.mark.integration
async def test_row2_every_public_waiter_raises_an_sdk_error_that_is_a_timeout() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        with pytest.raises(ChassisError) as waited:
            await robot.wait_for(lambda t: False, timeout=0.2)
        assert isinstance(waited.value, TimeoutError)
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        Chassis(sim.port, reconnect=True) as robot,
    ):
        states = robot.connection_states()
        sim.unplug()  # and not plugged back: the device reconnects for ever
        async for state in states:
            if state is ConnectionState.RECONNECTING:
                break
        with pytest.raises(ChassisError, match="not connected within 0.05 s") as connected:
            await robot.wait_connected(0.05)
        assert isinstance(connected.value, TimeoutError)


@pytest.mark.integration
async def test_confirm_times_out_when_the_device_does_not_show_the_effect() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port, link_timeout=None) as robot:
        await anext(robot.telemetry())
        sim.reset_firmware(downtime=2.0)  # rebooting: it hears nothing, sends nothing
        with pytest.raises(RequestTimeoutError, match="SOFTWARE_ESTOP set within 0.3 s"):
            await robot.emergency_stop(confirm=True, timeout=0.3)
        with pytest.raises(RequestTimeoutError, match="DOCKING_ENABLED"):
            await robot.start_docking(confirm=True, timeout=0.2)


# --- diagnose ------------------------------------------------------------------------------------


@pytest.mark.integration
async def test_diagnose_names_every_set_bit_per_wheel() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await anext(robot.telemetry())
        healthy = await robot.diagnose()
        assert healthy.ok, str(healthy)
        assert "status REMOTE_OFFLINE" in healthy.notes
        sim.firmware.press_bumper(front=False)
        sim.firmware.set_hardware_estop(True)
        sim.firmware.set_driver_fault(0, DriverError.OVER_CURRENT | DriverError.HALL_SENSOR)
        sim.firmware.set_driver_fault(2, DriverError(1 << 14))
        await robot.wait_for(lambda t: ChassisStatus.REAR_BUMPER in t.status, 1.0)
        report = await robot.diagnose()
    assert not report.ok
    assert set(report.faults) == {
        "status HARDWARE_ESTOP",
        "status FRONT_LEFT_DRIVER_ERROR",
        "status REAR_LEFT_DRIVER_ERROR",
        "status REAR_BUMPER",
        "front_left driver HALL_SENSOR",
        "front_left driver OVER_CURRENT",
        "front_left motor ERROR_WARNING",
        "rear_left driver DRIVER_OVER_TEMPERATURE_2",
        "rear_left motor ERROR_WARNING",
    }
    text = str(report)
    assert text.startswith("chassis on ")
    assert "9 fault(s)" in text
    assert "  FAULT  front_left driver OVER_CURRENT" in text
    assert report.drivers is not None
    assert report.status is not None


@pytest.mark.integration
async def test_board_diagnose_and_a_closed_device() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board:
        await anext(board.imu())
        await board.set_led(True)
        report = await board.diagnose()
    assert report.ok, str(report)
    assert "LED on" in report.notes
    closed = await board.diagnose()
    assert "link disconnected" in closed.faults


@pytest.mark.integration
async def test_row1_motion_blocked_is_the_device_s_own_public_answer() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.wait_for(lambda t: True, timeout=2.0)
        assert robot.motion_blocked() == ()
        await robot.emergency_stop()
        sim.firmware.hold_bumper(front=False)
        await robot.wait_for(lambda t: bool(t.status & ChassisStatus.REAR_BUMPER), timeout=2.0)
        assert robot.motion_blocked() == ("SOFTWARE_ESTOP", "REAR_BUMPER")
    async with BoardSimulator() as board_sim, Board(board_sim.port) as board:
        assert board.motion_blocked() == ()  # a board reports nothing that blocks it
