"""``chassis-sdk teleop``'s sans-IO parts: the key decoder, the key state machine and
its release timing, the gamepad mapping and its deadman; and a virtual gamepad
(evdev's ``UInput``) where ``/dev/uinput`` is usable."""

from __future__ import annotations

import argparse
import asyncio
import os
import time
from typing import Any

import pytest

from chassis_sdk.cli import build_parser
from chassis_sdk.teleop.gamepad import (
    ABS_CODES,
    BTN_CODES,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    SYN_DROPPED,
    SYN_REPORT,
    AxisRange,
    JoyMapping,
    JoyState,
    Pad,
    event_code,
)
from chassis_sdk.teleop.keys import (
    KEY_TIMEOUT,
    REPEAT_FLOOR,
    Effect,
    Key,
    KeyDecoder,
    KeyTeleop,
)

pytestmark = pytest.mark.surface  # a surface over the device (terminal teleop)

F, B, L, R = Key.FORWARD, Key.BACKWARD, Key.LEFT, Key.RIGHT

# --- the decoder ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("data", "keys"),
    [
        pytest.param(b"w", [F], id="w"),
        pytest.param(b"WASD", [F, L, B, R], id="WASD"),
        pytest.param(b"\x1b[A\x1b[B\x1b[C\x1b[D", [F, B, R, L], id="csi-arrows"),
        pytest.param(b"\x1bOA\x1bOB\x1bOC\x1bOD", [F, B, R, L], id="ss3-arrows"),
        pytest.param(b"\x1b[1;2A", [F], id="shift-up"),
        pytest.param(b"+=-_", [Key.FASTER, Key.FASTER, Key.SLOWER, Key.SLOWER], id="speed"),
        pytest.param(b" eErRqQ", [Key.STOP, *[Key.ESTOP] * 2, *[Key.RELEASE] * 2, *[Key.QUIT] * 2], id="commands"),
        pytest.param(b"\x03\x04", [Key.QUIT, Key.QUIT], id="ctrl-c-ctrl-d"),
        pytest.param(b"xyz\x00\x7f\xff\x1a\x13", [], id="unknown-ignored"),
        pytest.param(b"\x1b[5~w", [F], id="page-up-skipped"),
        pytest.param(b"\x1b[15~\x1bOPw", [F], id="function-keys-skipped"),
        pytest.param(b"\x1bw", [F], id="alt-w-as-w"),
        pytest.param(b"\x1b\x1b[A", [F], id="esc-then-arrow"),
    ],
)  # fmt: skip
def test_decoder_reads_keys(data: bytes, keys: list[Key]) -> None:
    assert KeyDecoder().feed(data) == keys
    one_by_one = KeyDecoder()  # every split across reads gives the same keys
    assert [k for i in range(len(data)) for k in one_by_one.feed(data[i : i + 1])] == keys


def test_decoder_waits_for_the_rest_of_a_split_sequence() -> None:
    d = KeyDecoder()
    assert d.feed(b"w\x1b") == [F]
    assert d.feed(b"[") == []
    assert d.feed(b"Dq") == [L, Key.QUIT]
    assert d.feed(b"\x1bO") == []
    assert d.feed(b"B") == [B]


def test_decoder_gives_up_on_a_runaway_sequence() -> None:
    d = KeyDecoder()
    assert d.feed(b"\x1b[" + b"1;" * 20) == []
    assert d.feed(b"w") == [F]


# --- the key state machine -----------------------------------------------------------------------


def machine(**kw: float) -> KeyTeleop:
    opts: dict[str, float] = {"max_linear": 0.5, "max_angular": 1.0, "speed": 0.3, **kw}
    return KeyTeleop(**opts)


def hold(t: KeyTeleop, data: bytes, start: float, delay: float, rate: float, n: int) -> float:
    """Play a held key: a press at ``start``, the first repeat ``delay`` later, then
    ``n`` more at ``rate`` Hz; return the time of the last arrival."""
    t.poll(start)  # the key held before is released by now
    assert t.feed(data, start) == [Effect.DRIVE]
    now = start + delay
    assert t.feed(data, now) == [Effect.DRIVE]
    for _ in range(n):
        now += 1 / rate
        assert t.feed(data, now) == [Effect.DRIVE]
    return now


def test_a_press_drives_at_the_scaled_speed_in_its_direction() -> None:
    t = machine()
    for data, velocity in [
        (b"w", (0.15, 0.0)),
        (b"s", (-0.15, 0.0)),
        (b"a", (0.0, 0.3)),
        (b"\x1b[C", (0.0, -0.3)),
    ]:
        assert t.feed(data, 0.0) == [Effect.DRIVE]
        assert t.velocity == pytest.approx(velocity)
    assert t.held is R  # a different key replaces the direction: no diagonals


@pytest.mark.parametrize(
    ("key_timeout", "delay", "rate", "repeating_bound"),
    [
        pytest.param(0.75, 0.5, 30, 0.15, id="gnome-500ms-30Hz"),
        pytest.param(0.75, 0.66, 25, 0.15, id="x11-660ms-25Hz"),
        pytest.param(0.75, 0.5, 15, 0.2, id="15Hz"),
        pytest.param(0.75, 0.25, 10.9, 3 / 10.9, id="console-250ms-11Hz"),
        pytest.param(0.2, 0.15, 12, 0.2, id="slow-repeat-capped-by-key-timeout"),
    ],
)  # fmt: skip
def test_release_bound_before_and_during_autorepeat(
    key_timeout: float, delay: float, rate: float, repeating_bound: float
) -> None:
    t = machine(key_timeout=key_timeout)
    # Before the first repeat: the key timeout from the press.
    assert t.feed(b"w", 10.0) == [Effect.DRIVE]
    assert t.deadline == pytest.approx(10.0 + key_timeout)
    assert t.poll(10.0 + key_timeout - 1e-6) == []
    assert t.poll(10.0 + key_timeout) == [Effect.STOP]
    assert t.held is None
    assert t.velocity == (0.0, 0.0)
    assert t.poll(20.0) == []  # told once
    # While repeating: 3 intervals, within [REPEAT_FLOOR, key_timeout].
    last = hold(t, b"w", 30.0, delay, rate, 10)
    assert t.timeout == pytest.approx(repeating_bound)
    assert t.deadline == pytest.approx(last + repeating_bound)
    assert t.poll(last + repeating_bound - 1e-6) == []
    assert t.poll(last + repeating_bound + 1e-9) == [Effect.STOP]


def test_the_initial_delay_is_learned_from_a_hold() -> None:
    t = machine()
    assert t.initial_timeout == KEY_TIMEOUT
    hold(t, b"w", 0.0, 0.25, 30, 5)  # the Linux console's 250 ms
    assert t.initial_timeout == pytest.approx(1.25 * 0.25 + 0.05)
    t.feed(b" ", 5.0)
    assert t.feed(b"w", 6.0) == [Effect.DRIVE]  # a tap now stops sooner
    assert t.poll(6.0 + 0.3625) == [Effect.STOP]
    # A longer delay (another terminal): the press stops once (a stutter), and the
    # delay is learned from the repeats that follow.
    assert t.feed(b"w", 10.0) == [Effect.DRIVE]
    assert t.poll(10.0 + 0.3625) == [Effect.STOP]
    hold(t, b"w", 10.5, 1 / 30, 30, 5)
    assert t.initial_timeout == pytest.approx(0.675)
    hold(t, b"w", 20.0, 0.6, 30, 5)  # longer than 0.5, within the timeout: no stutter
    assert t.initial_timeout == KEY_TIMEOUT  # 1.25 * 0.6 + 0.05 = 0.8, capped


def test_a_double_tap_is_not_taken_for_the_initial_delay() -> None:
    t = machine()
    t.feed(b"w", 0.0)
    t.feed(b"w", 0.15)  # a second tap
    t.feed(b"w", 0.65)  # then held: its own initial delay...
    t.feed(b"w", 0.68)  # ...and repeats
    assert t.initial_timeout == KEY_TIMEOUT


def test_one_late_repeat_does_not_stop_a_held_key() -> None:
    t = machine()
    last = hold(t, b"w", 0.0, 0.5, 30, 10)
    assert t.feed(b"w", last + 0.14) == [Effect.DRIVE]  # SSH jitter: 107 ms late
    assert t.timeout == pytest.approx(0.42)  # the longest of the last 4 gaps, x3
    assert t.held is F


def test_a_new_direction_starts_a_new_press() -> None:
    t = machine()
    last = hold(t, b"w", 0.0, 0.5, 30, 5)
    assert t.feed(b"a", last + 0.03) == [Effect.DRIVE]
    assert t.held is L
    assert t.deadline == pytest.approx(last + 0.03 + 0.675)  # its repeats start later


@pytest.mark.parametrize(
    ("data", "percent"),
    [
        pytest.param(b"+", 40, id="plus"),
        pytest.param(b"=", 40, id="equals"),
        pytest.param(b"-", 20, id="minus"),
        pytest.param(b"+" * 20, 100, id="clamped-at-100"),
        pytest.param(b"-" * 20, 10, id="clamped-at-10"),
        pytest.param(b"-" * 20 + b"+", 20, id="back-up"),
    ],
)  # fmt: skip
def test_plus_and_minus_step_the_speed_within_bounds(data: bytes, percent: int) -> None:
    t = machine()
    assert t.feed(data, 0.0) == []  # nothing held: nothing to write
    assert t.percent == percent


def test_a_speed_step_while_driving_rewrites_the_command() -> None:
    t = machine()
    t.feed(b"w", 0.0)
    assert t.feed(b"+", 0.1) == [Effect.DRIVE]
    assert t.velocity == pytest.approx((0.2, 0.0))
    t.feed(b"+" * 10, 0.2)
    assert t.feed(b"+", 0.3) == []  # already at 100 %: nothing new
    assert t.velocity == pytest.approx((0.5, 0.0))


def test_space_stops_e_estops_and_locks_out_drive_until_r() -> None:
    t = machine()
    t.feed(b"w", 0.0)
    assert t.feed(b" ", 0.1) == [Effect.STOP]
    assert t.held is None
    t.feed(b"w", 0.2)
    assert t.feed(b"e", 0.3) == [Effect.ESTOP]
    assert t.estopped
    assert t.held is None
    assert t.feed(b"w\x1b[A", 0.4) == []  # locked out
    assert t.velocity == (0.0, 0.0)
    assert t.feed(b"r", 0.5) == [Effect.RELEASE]
    assert t.feed(b"r", 0.6) == []  # nothing to release
    assert t.feed(b"w", 0.7) == [Effect.DRIVE]


@pytest.mark.parametrize("data", [b"q", b"Q", b"\x03"])
def test_q_and_ctrl_c_quit_with_nothing_held(data: bytes) -> None:
    t = machine()
    t.feed(b"w", 0.0)
    assert t.feed(data, 0.1) == [Effect.QUIT]
    assert t.quit
    assert t.held is None
    assert t.velocity == (0.0, 0.0)


def test_a_release_due_before_a_read_comes_before_its_keys() -> None:
    t = machine()
    t.feed(b"w", 0.0)
    assert t.feed(b"+", 1.0) == [Effect.STOP]  # w was released at 0.75


def test_bad_options_are_refused() -> None:
    for kw in ({"key_timeout": 0.0}, {"speed": 0.0}, {"speed": 1.5}, {"max_linear": -1.0}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            machine(**kw)


def test_the_floor_is_what_the_docs_say() -> None:
    assert (KEY_TIMEOUT, REPEAT_FLOOR) == (0.75, 0.15)


# --- the gamepad mapping -------------------------------------------------------------------------

X, Y = ABS_CODES["ABS_X"], ABS_CODES["ABS_Y"]
TL = BTN_CODES["BTN_TL"]
STICK = AxisRange(-32768, 32767)


def pad(**kw: float) -> JoyState:
    mapping = JoyMapping(scale_linear=0.5, scale_angular=1.0, **kw)  # type: ignore[arg-type]
    return JoyState(mapping, {X: STICK, Y: STICK}, {X: 0, Y: 0}, now=0.0)


def test_axis_normalisation() -> None:
    assert STICK.normalise(-32768) == -1.0
    assert STICK.normalise(32767) == 1.0
    assert STICK.normalise(0) == pytest.approx(0.0, abs=1e-4)
    assert AxisRange(0, 255).normalise(0) == -1.0
    assert AxisRange(0, 255).normalise(255) == 1.0
    with pytest.raises(ValueError, match="low < high"):
        AxisRange(5, 5)


def test_the_pad_drives_only_with_the_enable_button_held() -> None:
    j = pad()
    j.event(EV_ABS, Y, -32768, 0.1)  # stick up
    assert j.velocity(0.1) is None  # not enabled
    assert j.why(0.1) == "hold BTN_TL"
    j.event(EV_KEY, TL, 1, 0.2)
    assert j.velocity(0.2) == pytest.approx((0.5, 0.0))  # up = forward
    j.event(EV_ABS, X, -32768, 0.3)  # stick left
    assert j.velocity(0.3) == pytest.approx((0.5, 1.0))  # left = turn left
    j.event(EV_KEY, TL, 0, 0.4)
    assert j.velocity(0.4) is None


def test_deadzone_reads_zero_and_stretches_the_rest() -> None:
    j = pad(deadzone=0.2)
    j.event(EV_KEY, TL, 1, 0.0)
    j.event(EV_ABS, Y, -6000, 0.0)  # -0.18: inside
    assert j.velocity(0.0) == (0.0, 0.0)
    j.event(EV_ABS, Y, -19660, 0.0)  # -0.6: (0.6 - 0.2) / 0.8 = 0.5
    lin, ang = j.velocity(0.0) or (None, None)
    assert lin == pytest.approx(0.25, abs=1e-3)
    assert ang == 0.0


def test_negative_scales_invert() -> None:
    mapping = JoyMapping(scale_linear=-0.5, scale_angular=-1.0)
    j = JoyState(mapping, {X: STICK, Y: STICK}, {X: 0, Y: 0}, now=0.0)
    j.event(EV_KEY, TL, 1, 0.0)
    j.event(EV_ABS, Y, -32768, 0.0)
    j.event(EV_ABS, X, 32767, 0.0)
    assert j.velocity(0.0) == pytest.approx((-0.5, 1.0))


def test_an_out_of_range_value_stops_until_a_good_one_arrives() -> None:
    j = pad()
    j.event(EV_KEY, TL, 1, 0.0)
    j.event(EV_ABS, Y, -32768, 0.0)
    j.event(EV_ABS, Y, 40000, 0.1)
    assert j.velocity(0.1) is None
    assert j.refused == 1
    assert j.why(0.1) == "ABS_Y 40000 outside [-32768, 32767]"
    j.event(EV_ABS, Y, -32768, 0.2)
    assert j.velocity(0.2) == pytest.approx((0.5, 0.0))


def test_a_silent_pad_stops_and_the_next_event_resumes() -> None:
    j = pad(timeout=1.0)
    j.event(EV_KEY, TL, 1, 0.0)
    j.event(EV_ABS, Y, -32768, 0.0)
    j.event(EV_SYN, SYN_REPORT, 0, 0.0)
    assert j.deadline == 1.0
    assert j.velocity(0.999) is not None
    assert j.velocity(1.0) is None
    assert j.why(1.0) == "pad silent"
    j.event(EV_ABS, Y, -32700, 1.5)
    assert j.velocity(1.5) is not None
    off = pad(timeout=0.0)  # 0: never silent
    off.event(EV_KEY, TL, 1, 0.0)
    assert off.deadline is None
    assert off.velocity(1e6) == (0.0, 0.0)


def test_dropped_events_need_a_fresh_enable_press_and_fresh_axes() -> None:
    j = pad()
    j.event(EV_KEY, TL, 1, 0.0)
    j.event(EV_ABS, Y, -32768, 0.05)  # full forward ...
    assert j.velocity(0.05) is not None
    j.event(EV_SYN, SYN_DROPPED, 0, 0.1)  # ... and its return to the centre was lost
    assert j.velocity(0.1) is None
    j.event(EV_KEY, TL, 1, 0.2)
    assert j.velocity(0.2) is None  # the stale "full forward" never drives
    j.event(EV_ABS, Y, 0, 0.3)
    assert j.velocity(0.3) is None  # the other mapped axis is unknown still
    j.event(EV_ABS, X, 0, 0.4)
    assert j.velocity(0.4) == (0.0, 0.0)


def test_a_key_timeout_beyond_two_seconds_is_refused() -> None:
    with pytest.raises(ValueError, match="key_timeout"):
        machine(key_timeout=7.5)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["teleop", "/dev/null", "--key-timeout", "7.5"])
    with pytest.raises(SystemExit):
        build_parser().parse_args(["teleop", "/dev/null", "--joy-timeout", "30"])


def test_a_button_held_at_start_does_not_enable() -> None:
    j = pad()  # no press event since the start: not enabled whatever its state
    j.event(EV_ABS, Y, -32768, 0.1)
    assert j.velocity(0.1) is None


def test_mapping_options_are_checked() -> None:
    assert event_code("btn_tl", BTN_CODES, "x") == 0x136
    assert event_code("0x136", BTN_CODES, "x") == 0x136
    assert event_code("310", BTN_CODES, "x") == 310
    with pytest.raises(ValueError, match="BTN_TL"):
        event_code("LB", BTN_CODES, "--enable-button")
    with pytest.raises(ValueError, match="must differ"):
        JoyMapping(scale_linear=1, scale_angular=1, linear_axis=X, angular_axis=X)
    with pytest.raises(ValueError, match="joy_deadzone"):
        JoyMapping(scale_linear=1, scale_angular=1, deadzone=1.0)
    with pytest.raises(ValueError, match="no range"):
        JoyState(JoyMapping(scale_linear=1, scale_angular=1), {X: STICK}, {}, 0.0)


def test_the_parser_takes_names_and_defaults() -> None:
    args: argparse.Namespace = build_parser().parse_args(
        ["teleop", "/dev/null", "--enable-button", "BTN_SOUTH", "--linear-axis", "ABS_RY"]
    )
    assert args.enable_button == BTN_CODES["BTN_SOUTH"]
    assert args.linear_axis == ABS_CODES["ABS_RY"]
    assert args.angular_axis == X
    assert (args.key_timeout, args.speed, args.joy_timeout) == (0.75, 0.3, 1.0)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["teleop", "/dev/null", "--enable-button", "nope"])


# --- a virtual gamepad ---------------------------------------------------------------------------


def _uinput_usable() -> str | None:
    """Why a virtual pad cannot be made here, or ``None``."""
    try:
        import evdev  # noqa: F401
    except ImportError:
        return "evdev is not installed"
    if not os.path.exists("/dev/uinput"):
        return (
            "/dev/uinput does not exist here (no uinput module or not passed into the "
            "container): the mapping and deadman are tested above without a device"
        )
    if not os.access("/dev/uinput", os.R_OK | os.W_OK):
        return "/dev/uinput is not readable and writable by this user"
    return None


@pytest.mark.skipif(_uinput_usable() is not None, reason=str(_uinput_usable()))
async def test_a_virtual_pad_drives_and_its_unplug_is_seen() -> None:
    from evdev import AbsInfo, UInput, ecodes

    info = AbsInfo(value=0, min=-32768, max=32767, fuzz=0, flat=0, resolution=0)
    caps: dict[int, Any] = {ecodes.EV_KEY: [TL], ecodes.EV_ABS: [(X, info), (Y, info)]}
    ui = UInput(caps, name="chassis-sdk test pad")
    try:
        path = str(ui.device.path)
        mapping = JoyMapping(scale_linear=0.5, scale_angular=1.0, timeout=0.0)
        p = Pad(path, mapping, time.monotonic())
        changed = asyncio.Event()
        p.start(time.monotonic, changed.set)
        ui.write(ecodes.EV_KEY, TL, 1)
        ui.write(ecodes.EV_ABS, Y, -32768)
        ui.syn()
        async with asyncio.timeout(5):
            while p.state.velocity(time.monotonic()) != pytest.approx((0.5, 0.0)):
                changed.clear()
                await changed.wait()
    finally:
        ui.close()  # unplugged
    async with asyncio.timeout(5):
        while p.gone is None:
            changed.clear()
            await changed.wait()
    assert "unplugged" in p.gone
    p.close()
