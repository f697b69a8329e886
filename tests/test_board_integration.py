"""Board over a real pty, through the real transport, against the independent stand-in
(with noise on the line) and against the simulator."""

from __future__ import annotations

import asyncio
import math
import struct
import time

import pytest

from chassis_sdk import Board, Motor, RequestTimeoutError
from chassis_sdk.sim import BoardSimulator

from .support.standin import BoardStandIn, Received

pytestmark = pytest.mark.integration


def velocity_frames(frames: list[Received]) -> list[Received]:
    return [f for f in frames if f.kind == 0x22]


def is_zero(rec: Received) -> bool:
    return rec.payload == b"\x00\x00\x00\x00"


async def test_streams_decode_and_scale() -> None:
    async with BoardStandIn() as dev, Board(dev.port) as board:
        imu = await anext(board.imu())
        vel = await anext(board.velocity())
        bat = await anext(board.battery())
        stats = board.stats
    assert tuple(imu.accel) == (1.0, -0.5, 1.0)
    assert tuple(imu.gyro) == (0.0, -10.0, 10.0)
    assert tuple(imu.mag) == (300.0, -300.0, -420.0)
    assert (vel.linear, vel.angular) == (0.25, -0.5)
    assert bat.voltage == 12.34
    assert board.latest_imu is not None
    assert board.latest_velocity == vel or board.latest_velocity is not None
    assert stats.bytes_dropped > 0  # there was noise, and it was skipped


async def test_replies_in_reverse_order_reach_the_right_callers() -> None:
    async with BoardStandIn(hold_replies=6) as dev, Board(dev.port) as board:
        results = await asyncio.gather(
            board.set_led(True),
            board.get_led(),
            board.set_buzzer(True),
            board.get_buzzer(),
            board.set_led(False),
            board.get_buzzer(),
        )
    # The stand-in applied the commands in order and answered in reverse: each caller
    # still gets the state reported for its own request.
    assert list(results) == [True, True, True, True, False, True]
    ids = [f.payload[1] for f in dev.frames if f.kind in (1, 2)]
    assert len(set(ids)) == len(ids) == 6


async def test_many_concurrent_requests_get_distinct_ids() -> None:
    async with BoardStandIn() as dev, Board(dev.port) as board:
        results = await asyncio.gather(*(board.get_led() for _ in range(300)))
        assert results == [False] * 300
        assert board.stats.unmatched_replies == 0
    assert len(dev.of_kind(0x01)) == 300


async def test_request_ids_skip_ids_still_in_flight() -> None:
    async with BoardStandIn(hold_replies=3) as dev, Board(dev.port) as board:
        board._next_id = 254
        await asyncio.gather(board.get_led(), board.get_led(), board.get_buzzer())
    assert [f.payload[1] for f in dev.frames if f.kind in (1, 2)] == [254, 255, 0]


@pytest.mark.timing
async def test_request_timeout_for_silent_board() -> None:
    async with (
        BoardStandIn(silent=True) as dev,
        Board(dev.port, request_timeout=0.1, retries=1) as board,
    ):
        t0 = time.monotonic()
        with pytest.raises(RequestTimeoutError):
            await board.get_led()
        assert time.monotonic() - t0 < 0.45
        with pytest.raises(RequestTimeoutError):
            await board.set_led(True)  # not read-only: one attempt only
    assert len(dev.of_kind(0x01)) == 3


async def test_exact_bytes_for_pwm_servo_and_velocity() -> None:
    async with BoardStandIn(noise=False) as dev, Board(dev.port) as board:
        logs = board.logs()  # subscribe first: the log line answers the servo frame
        await board.set_motor_pwm(Motor.REAR_LEFT, 4000)
        await board.set_servo(1, 30)
        await board.set_velocity(0.5, 0.5)
        await board.stop()
        assert await anext(logs) == "servo 1 at 30.0"
    raws = [f.raw for f in dev.frames]
    assert raws[0] == bytes.fromhex("AB BC 21 04 01 A0 0F D5")
    assert raws[1] == bytes.fromhex("AB BC 31 04 01 2C 01 63")
    assert raws[2] == bytes.fromhex("ab bc 22 05 f4 01 f4 01 11")
    assert is_zero(velocity_frames(dev.frames)[-1])


@pytest.mark.parametrize(
    ("call", "args", "match"),
    [
        pytest.param("set_motor_pwm", (0, 100), "unknown motor", id="motor-0"),
        pytest.param("set_motor_pwm", (5, 100), "unknown motor", id="motor-5"),
        pytest.param("set_motor_pwm", (1, 40000), "out of range", id="pwm-overflow"),
        pytest.param("set_servo", (3, 10.0), "unknown servo", id="servo-3"),
        pytest.param("set_servo", (1, 4000.0), "out of range", id="servo-overflow"),
        pytest.param("set_servo", (1, math.nan), "finite", id="servo-nan"),
        pytest.param("set_velocity", (math.nan, 0.0), "finite", id="velocity-nan"),
        pytest.param("set_velocity", (0.0, 33.0), "out of range", id="velocity-overflow"),
    ],
)
async def test_bad_arguments_raise_before_anything_is_written(
    call: str, args: tuple[float, float], match: str
) -> None:
    async with BoardStandIn(noise=False) as dev, Board(dev.port) as board:
        with pytest.raises(ValueError, match=match):
            await getattr(board, call)(*args)
        assert await board.get_led() is False
        assert [f.kind for f in dev.frames] == [0x01]


@pytest.mark.timing
async def test_watchdog_and_deadman() -> None:
    async with (
        BoardStandIn(noise=False) as dev,
        Board(dev.port, resend_interval=0.02, command_timeout=0.2) as board,
    ):
        t0 = time.monotonic()
        await board.set_velocity(0.3, -0.2)
        await dev.wait_for(lambda fs: any(is_zero(f) for f in velocity_frames(fs)))
        elapsed = time.monotonic() - t0
    frames = velocity_frames(dev.frames)
    nonzero = [f for f in frames if not is_zero(f)]
    assert all(struct.unpack("<hh", f.payload) == (300, -200) for f in nonzero)
    assert len(nonzero) >= 6  # resent every 20 ms for 200 ms
    assert 0.18 <= elapsed <= 0.4


async def test_zero_velocity_on_exit() -> None:
    async with BoardStandIn(noise=False) as dev:
        async with Board(dev.port, command_timeout=None) as board:
            await board.set_velocity(0.2, 0.0)
            await dev.wait_for(lambda fs: len(velocity_frames(fs)) >= 3)
        await dev.wait_for(lambda fs: is_zero(velocity_frames(fs)[-1]))


async def test_two_subscribers_receive_the_same_samples() -> None:
    async with BoardStandIn() as dev, Board(dev.port) as board:
        a, b = board.imu(), board.imu()
        xs = [await anext(a) for _ in range(10)]
        ys = [await anext(b) for _ in range(10)]
        assert [s.timestamp for s in xs] == [s.timestamp for s in ys]
        assert dev.frames == []  # the streams are unprompted: reading asks the board nothing


async def test_simulator_led_imu_follows_motion_and_logs() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board:
        logs = board.logs()
        assert await board.set_led(True) is True
        assert await board.get_led() is True
        assert await board.set_buzzer(True) is True
        assert await board.set_buzzer(False) is False
        await board.set_servo(2, 45.5)
        lines = []
        while (line := await anext(logs)) != "servo 2 -> 45.5 deg":
            lines.append(line)
        assert lines[-3:] == ["led on", "buzzer on", "buzzer off"]  # in the order asked
        assert sim.firmware.servo[2] == 45.5
        await board.set_velocity(0.3, 1.0)
        async for s in board.imu():
            await board.set_velocity(0.3, 1.0)
            if s.gyro.z > 55:  # 1 rad/s = 57.3 deg/s once the ramp is done
                assert s.accel.z == pytest.approx(1.0, abs=0.05)
                break
        async for v in board.velocity():
            if v.linear == pytest.approx(0.3, abs=0.01):
                break
        assert (await anext(board.battery())).voltage > 11


async def test_with_every_request_id_retired_a_request_times_out_cleanly() -> None:
    async with (
        BoardStandIn(silent=True) as dev,
        Board(dev.port, request_timeout=0.05, retries=0) as board,
    ):
        # 256 unanswered requests retire every id (their replies are overdue).
        results = await asyncio.gather(
            *(board.get_led() for _ in range(256)), return_exceptions=True
        )
        assert all(isinstance(r, RequestTimeoutError) for r in results)
        with pytest.raises(RequestTimeoutError, match="no request id came free"):
            await board.get_led()
        assert len(dev.of_kind(0x01)) == 256  # nothing was sent for the last one


async def test_a_board_imu_scale_applies_to_samples_and_the_diagnosis() -> None:
    from chassis_sdk import ImuScale
    from chassis_sdk.sim import BoardSimulator

    async with BoardSimulator() as sim, Board(sim.port) as board:
        assert board.imu_scale == ImuScale()
        first = await anext(board.imu())
        assert first.accel.z == pytest.approx(1.0, abs=0.05)  # the document's scale
        assert any(n.startswith("IMU reads |a| = ") for n in (await board.diagnose()).notes)
        board.imu_scale = ImuScale(accel=16384.0, gyro=65.5)
        sample = await anext(board.imu())
        assert sample.raw is not None
        assert sample.accel.z == pytest.approx(sample.raw.accel_z / 16384.0)
        report = await board.diagnose()
        assert any(f.startswith("IMU reads |a| = 0.01 g") for f in report.faults)
        with pytest.raises(TypeError, match="ImuScale"):
            board.imu_scale = 164.0  # type: ignore[assignment]
