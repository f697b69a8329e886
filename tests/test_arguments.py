"""Bad numbers are refused before a byte is written, for every call of both devices,
and by the settings that take a number without a device to talk to (the timeouts,
``MotionLimits``, ``reset_odometry``) (field hardening, issue 11): as the standard
library does, a wrong type (a bool, a string, ``None``) is a ``TypeError`` and a bad
value (NaN, infinities, huge numbers) a ``ValueError`` (issue 28 row 18); a servo angle
out of the board's range is refused too.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from chassis_sdk import Board, Chassis, MotionLimits
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.helpers import drives
from .support.standin import BoardStandIn, ChassisStandIn, drive_frames

BAD = [
    pytest.param(float("nan"), id="nan"),
    pytest.param(float("inf"), id="inf"),
    pytest.param(-float("inf"), id="-inf"),
    pytest.param(1e308, id="1e308"),
    pytest.param(-1e308, id="-1e308"),
    pytest.param(10**400, id="10**400"),
    pytest.param(1e30, id="1e30"),
    pytest.param(True, id="bool"),
    pytest.param("1", id="str"),
    pytest.param(None, id="None"),
]

#: What each bad value raises: the wrong types a TypeError, the rest a ValueError.
WRONG_TYPES = (True, "1", None)


def _error_of(bad: Any, allows: str = "") -> type[Exception]:
    """A wrong type is a TypeError; so is a float where an integer is wanted ("int")."""
    wrong = any(bad is t for t in WRONG_TYPES) or ("int" in allows and isinstance(bad, float))
    return TypeError if wrong else ValueError


#: (name, call, what a valid value of the argument may also be): a large positive
#: number is a valid time or factor, ``None`` a valid "not given".
_CHASSIS_CALLS: list[tuple[str, Callable[[Chassis, Any], Awaitable[Any]], str]] = [
    ("set_velocity linear", lambda r, x: r.set_velocity(x, 0.0), ""),
    ("set_velocity angular", lambda r, x: r.set_velocity(0.0, x), ""),
    ("set_velocity duration", lambda r, x: r.set_velocity(0.1, 0.0, duration=x), "large none"),
    ("set_wheel_speeds left", lambda r, x: r.set_wheel_speeds(x, 0.0), ""),
    ("set_wheel_speeds right", lambda r, x: r.set_wheel_speeds(0.0, x), ""),
    ("set_wheel_speeds duration", lambda r, x: r.set_wheel_speeds(0, 0, duration=x), "large none"),
    ("wait_for timeout", lambda r, x: r.wait_for(lambda t: True, x), "large"),
    (
        "configure_odometry slip",
        lambda r, x: r.configure_odometry("wheels", slip_factor=x, track_width=0.5),
        "large",
    ),
    (
        "configure_odometry track",
        lambda r, x: r.configure_odometry("wheels", track_width=x),
        "large none",
    ),
    ("configure_odometry gap", lambda r, x: r.configure_odometry(max_gap=x), "large"),
]
_BOARD_CALLS: list[tuple[str, Callable[[Board, Any], Awaitable[Any]], str]] = [
    ("set_velocity linear", lambda b, x: b.set_velocity(x, 0.0), ""),
    ("set_velocity angular", lambda b, x: b.set_velocity(0.0, x), ""),
    ("set_velocity duration", lambda b, x: b.set_velocity(0.1, 0.0, duration=x), "large none"),
    ("set_motor_pwm pwm", lambda b, x: b.set_motor_pwm(1, x), "int"),
    ("set_motor_pwm motor", lambda b, x: b.set_motor_pwm(x, 10), "int"),
    ("set_servo angle", lambda b, x: b.set_servo(1, x), ""),
    ("set_servo servo", lambda b, x: b.set_servo(x, 10.0), "int"),
    ("configure_odometry gap", lambda b, x: b.configure_odometry(max_gap=x), "large"),
]
_MAKERS: list[tuple[str, Callable[[Any], object], str]] = [
    ("request_timeout", lambda x: Chassis("/dev/null", request_timeout=x), "large"),
    ("connect_timeout", lambda x: Chassis("/dev/null", connect_timeout=x), "large"),
    ("MotionLimits", lambda x: MotionLimits(max_linear=x), "large none"),
    ("reset_odometry", lambda x: Chassis("/dev/null").reset_odometry(x, 0.0), "large negative"),
]


def _valid_anyway(bad: Any, allows: str) -> bool:
    if bad is None:
        return "none" in allows
    if bad in (1e30, 1e308):
        return "large" in allows
    return bad == -1e308 and "negative" in allows


@pytest.mark.integration
@pytest.mark.parametrize("bad", BAD)
async def test_every_bad_number_is_refused_before_a_byte_is_written(bad: Any) -> None:
    async with (
        ChassisStandIn(noise=False) as cdev,
        BoardStandIn(noise=False) as bdev,
        Chassis(cdev.port) as robot,
        Board(bdev.port) as board,
    ):
        calls: list[tuple[Any, str, Callable[[Any, Any], Awaitable[Any]], str]] = [
            *((robot, *c) for c in _CHASSIS_CALLS),
            *((board, *c) for c in _BOARD_CALLS),
        ]
        for device, name, call, allows in calls:
            if _valid_anyway(bad, allows):
                continue
            sent = device.stats.frames_sent
            error = _error_of(bad, allows)
            with pytest.raises(error, match=r"must be|out of range|unknown") as info:
                await call(device, bad)
            assert type(info.value) is error, name  # exactly, not a subclass
            assert device.stats.frames_sent == sent, name
        # Nothing was written for any of them (the stand-ins heard no command at all).
        assert drive_frames(cdev.frames) == []
        assert bdev.frames == []
    for _name, make, allows in _MAKERS:
        if not _valid_anyway(bad, allows):
            with pytest.raises(_error_of(bad), match="must be"):
                make(bad)


@pytest.mark.integration
async def test_row18_a_wrong_type_is_a_type_error_and_nothing_is_written() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        for linear in ("0.1", None, True):
            with pytest.raises(TypeError, match="linear must be a number"):
                await robot.set_velocity(linear, 0)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="linear must be finite"):
            await robot.set_velocity(float("nan"), 0)
        await robot.get_firmware_version()  # everything written before it has arrived
        assert drives(sim) == []


@pytest.mark.integration
async def test_row18_the_servo_range_is_enforced_before_a_byte_is_written() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as board:
        assert board.servo_range == (0.0, 180.0)
        for angle in (400.0, -0.1, 180.1):
            with pytest.raises(ValueError, match="out of range: the servo takes 0 to 180"):
                await board.set_servo(1, angle)
        with pytest.raises(TypeError, match="angle must be a number"):
            await board.set_servo(1, "90")  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="not an integer"):
            await board.set_servo(1.0, 90)  # type: ignore[arg-type]
        assert sim.firmware.servo == {1: 0.0, 2: 0.0}
        await board.set_servo(1, 180)
        await board.set_servo(2, 0.0)
        await board.get_led()  # the servo frames have arrived by its reply
        assert sim.firmware.servo == {1: 180.0, 2: 0.0}


def test_wrong_types_are_type_errors_and_bad_values_value_errors() -> None:
    from chassis_sdk import Chassis
    from chassis_sdk.integrations.access import check_token
    from chassis_sdk.integrations.inbound import check_topic_level

    with pytest.raises(TypeError, match="port must be"):
        Chassis(5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="port must be"):
        Chassis("")
    with pytest.raises(TypeError, match="token must be a string"):
        check_token(12345678901234567890)
    with pytest.raises(ValueError, match="at least"):
        check_token("short")
    with pytest.raises(TypeError, match="robot_id must be a string"):
        check_topic_level(7, "robot_id")
    with pytest.raises(ValueError, match="letters, digits"):
        check_topic_level("a/b#", "robot_id")
