"""``chassis-sdk teleop --joystick``: a gamepad on the robot computer, read through
Linux evdev (the optional extra ``joystick``).

`JoyState` is the mapping, sans-IO (events and ``now`` in, a command out), as
teleop_twist_joy's: an enable button that must be held (a deadman: released, the robot
stops), a linear and an angular axis normalised from the axis's own ``absinfo`` range
to -1..1, a deadzone, and a scale per axis (negative inverts). `Pad` reads a
device from the event loop (``add_reader``, no thread) and feeds it.

When a pad stops the robot:

- the enable button is released, or was never pressed since teleop started (holding
  it at start does not count: it must be pressed);
- the pad is unplugged (a read fails with ``ENODEV``): at once, and teleop ends;
- a value outside the axis's ``absinfo`` range arrives: refused, the robot stops until
  a value within range arrives on that axis;
- the kernel dropped events (``SYN_DROPPED``): the state is unknown, so the enable
  button must be pressed again;
- the pad is *silent*: no event at all for ``timeout`` seconds while enabled. evdev
  reports changes only, so a pad whose radio link froze and a stick held perfectly
  still look the same; joy_node (what teleop_twist_joy relies on) hides the
  difference by republishing, which detects neither. Here silence stops the robot and
  the next event (any stick movement) resumes it: with ``--joy-timeout 1`` a stick held
  exactly still (against its stop, say) for a second stops the robot until it moves
  again; ``--joy-timeout 0`` turns the check off, leaving unplug detection and the
  enable button.
"""

from __future__ import annotations

import asyncio
import errno
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from ..core.validation import check_real
from ..errors import ChassisError, install_hint

__all__ = [
    "ABS_CODES",
    "BTN_CODES",
    "JOYSTICK_HINT",
    "AxisRange",
    "JoyMapping",
    "JoyState",
    "Pad",
    "event_code",
]

#: The one-line error when evdev is missing.
JOYSTICK_HINT = f"--joystick needs evdev: {install_hint('joystick')}"

# Linux input event codes (linux/input-event-codes.h: the kernel's ABI, so they are
# known here without evdev installed, and options are checked before anything opens).
EV_SYN, EV_KEY, EV_ABS = 0x00, 0x01, 0x03
SYN_REPORT, SYN_DROPPED = 0, 3
#: Axis names for ``--linear-axis``/``--angular-axis``.
ABS_CODES: dict[str, int] = {
    "ABS_X": 0x00,
    "ABS_Y": 0x01,
    "ABS_Z": 0x02,
    "ABS_RX": 0x03,
    "ABS_RY": 0x04,
    "ABS_RZ": 0x05,
    "ABS_THROTTLE": 0x06,
    "ABS_RUDDER": 0x07,
    "ABS_WHEEL": 0x08,
    "ABS_GAS": 0x09,
    "ABS_BRAKE": 0x0A,
    "ABS_HAT0X": 0x10,
    "ABS_HAT0Y": 0x11,
}
#: Button names for ``--enable-button``.
BTN_CODES: dict[str, int] = {
    "BTN_TRIGGER": 0x120,
    "BTN_THUMB": 0x121,
    "BTN_THUMB2": 0x122,
    "BTN_TOP": 0x123,
    "BTN_TOP2": 0x124,
    "BTN_PINKIE": 0x125,
    "BTN_SOUTH": 0x130,
    "BTN_A": 0x130,
    "BTN_EAST": 0x131,
    "BTN_B": 0x131,
    "BTN_C": 0x132,
    "BTN_NORTH": 0x133,
    "BTN_X": 0x133,
    "BTN_WEST": 0x134,
    "BTN_Y": 0x134,
    "BTN_Z": 0x135,
    "BTN_TL": 0x136,
    "BTN_TR": 0x137,
    "BTN_TL2": 0x138,
    "BTN_TR2": 0x139,
    "BTN_SELECT": 0x13A,
    "BTN_START": 0x13B,
    "BTN_MODE": 0x13C,
    "BTN_THUMBL": 0x13D,
    "BTN_THUMBR": 0x13E,
}


def event_code(text: str, names: Mapping[str, int], what: str) -> int:
    """An event code from a name in ``names`` (any case) or a number (``0x136`` too).

    Raises:
        ValueError: Neither; the message lists the names.
    """
    code = names.get(text.strip().upper())
    if code is not None:
        return code
    try:
        number = int(text, 0)
    except ValueError:
        raise ValueError(
            f"{what} must be a number or one of {', '.join(names)}; got {text!r}"
        ) from None
    if not 0 <= number <= 0x2FF:
        raise ValueError(f"{what} must be from 0 to 767, got {number}")
    return number


def code_name(code: int, names: Mapping[str, int]) -> str:
    """The first name of ``code`` in ``names``, else its number."""
    return next((n for n, c in names.items() if c == code), str(code))


@dataclass(frozen=True, slots=True)
class AxisRange:
    """An axis's ``absinfo`` range: the raw values from ``low`` to ``high``."""

    low: int
    high: int

    def __post_init__(self) -> None:
        if self.low >= self.high:
            raise ValueError(f"an axis range needs low < high, got [{self.low}, {self.high}]")

    def normalise(self, value: int) -> float:
        """``value`` mapped to -1..1 (``low`` to -1, ``high`` to 1)."""
        half = (self.high - self.low) / 2
        return min(max((value - self.low) / half - 1.0, -1.0), 1.0)


@dataclass(frozen=True, slots=True)
class JoyMapping:
    """How a pad drives, as teleop_twist_joy's parameters.

    Attributes:
        scale_linear: m/s at the linear axis's *low* end (stick up on a gamepad, whose
            Y axis grows downwards); negative inverts.
        scale_angular: rad/s at the angular axis's low end (stick left: a left turn);
            negative inverts.
        enable_button: The deadman button's code (default ``BTN_TL``, the left bumper).
        linear_axis, angular_axis: Axis codes (default ``ABS_Y``, ``ABS_X``: the left
            stick).
        deadzone: The part of each half-axis around the centre read as zero (0 to
            <1); the rest is stretched back to 0..1, so the output has no jump.
        timeout: Seconds without any event while enabled that count as a silent pad
            (0: never).
    """

    scale_linear: float
    scale_angular: float
    enable_button: int = BTN_CODES["BTN_TL"]
    linear_axis: int = ABS_CODES["ABS_Y"]
    angular_axis: int = ABS_CODES["ABS_X"]
    deadzone: float = 0.1
    timeout: float = 1.0

    def __post_init__(self) -> None:
        check_real(self.scale_linear, "joy_scale_linear")
        check_real(self.scale_angular, "joy_scale_angular")
        check_real(self.deadzone, "joy_deadzone", low=0, high=0.99)
        check_real(self.timeout, "joy_timeout", low=0, unit="s")
        if self.linear_axis == self.angular_axis:
            raise ValueError("the linear and the angular axis must differ")


class JoyState:
    """The pad's state from its events, and the command it gives.

    Args:
        mapping: The mapping.
        ranges: ``absinfo`` range of each mapped axis.
        values: The axes' values when the pad was opened (``absinfo.value``).
        now: The time of opening (the same clock as every later ``now``).

    Raises:
        ValueError: A mapped axis without a range.
    """

    def __init__(
        self,
        mapping: JoyMapping,
        ranges: Mapping[int, AxisRange],
        values: Mapping[int, int],
        now: float,
    ) -> None:
        self.mapping = mapping
        for axis in (mapping.linear_axis, mapping.angular_axis):
            if axis not in ranges:
                raise ValueError(f"no range for axis {code_name(axis, ABS_CODES)}")
        self._ranges = dict(ranges)
        self._axes: dict[int, float | None] = dict.fromkeys(self._ranges, 0.0)
        for axis, value in values.items():
            if axis in self._ranges:
                self.axis(axis, value, now)
        #: The enable button is held (pressed since the start).
        self.enabled = False
        #: ``time.monotonic()`` (or whatever clock ``now`` is) of the last event.
        self.last_event = now
        #: Values refused as out of range, so far.
        self.refused = 0
        self._why: str | None = None

    def event(self, etype: int, code: int, value: int, now: float) -> None:
        """One evdev event (``type``, ``code``, ``value``) at ``now``."""
        self.last_event = now
        if etype == EV_KEY and code == self.mapping.enable_button:
            self.enabled = value != 0  # 1 pressed, 2 its autorepeat, 0 released
        elif etype == EV_ABS and code in self._ranges:
            self.axis(code, value, now)
        elif etype == EV_SYN and code == SYN_DROPPED:
            # Events were lost: the button and every axis are unknown (the stick's
            # return to the centre may be among them) until each reports again.
            self.enabled = False
            for axis in self._axes:
                self._axes[axis] = None
            self._why = "events dropped: press enable again and move the stick"

    def axis(self, code: int, value: int, now: float) -> None:
        """An axis's new raw value; out of its range it is refused and the axis is
        unknown until a value within range arrives."""
        del now
        span = self._ranges[code]
        if not span.low <= value <= span.high:
            self._axes[code] = None
            self.refused += 1
            name = code_name(code, ABS_CODES)
            self._why = f"{name} {value} outside [{span.low}, {span.high}]"
            return
        self._axes[code] = self._dead(span.normalise(value))

    def _dead(self, x: float) -> float:
        d = self.mapping.deadzone
        if abs(x) <= d:
            return 0.0
        return (abs(x) - d) / (1 - d) * (1.0 if x > 0 else -1.0)

    def silent(self, now: float) -> bool:
        """No event for the mapping's ``timeout`` at ``now`` (never with timeout 0)."""
        timeout = self.mapping.timeout
        return bool(timeout) and now - self.last_event >= timeout

    @property
    def deadline(self) -> float | None:
        """When the pad counts as silent unless an event arrives, while enabled."""
        if not self.enabled or not self.mapping.timeout:
            return None
        return self.last_event + self.mapping.timeout

    def velocity(self, now: float) -> tuple[float, float] | None:
        """``(linear, angular)`` the pad commands at ``now``, or ``None`` when it does
        not drive: enable not held, silent, or a mapped axis out of range."""
        if not self.enabled or self.silent(now):
            return None
        x = self._axes[self.mapping.linear_axis]
        y = self._axes[self.mapping.angular_axis]
        if x is None or y is None:
            return None
        return (-x * self.mapping.scale_linear + 0.0, -y * self.mapping.scale_angular + 0.0)

    def why(self, now: float) -> str:
        """Why the pad does not drive now (for the status line), or ``""``."""
        m = self.mapping
        if any(self._axes[a] is None for a in (m.linear_axis, m.angular_axis)):
            return self._why or "axis out of range"
        if self.enabled and self.silent(now):
            return "pad silent"
        if not self.enabled:
            return f"hold {code_name(m.enable_button, BTN_CODES)}"
        return ""


class Pad:
    """An evdev gamepad read from the running event loop (no thread).

    Args:
        path: The device, ``/dev/input/eventN`` (``/dev/input/by-id/...`` is stable).
        mapping: How it drives.
        now: The clock's reading at opening.

    Raises:
        ChassisError: evdev missing, the device cannot be opened, or it lacks a mapped
            axis or the enable button (one line).
    """

    def __init__(self, path: str, mapping: JoyMapping, now: float) -> None:
        try:
            import evdev
        except ImportError:
            raise ChassisError(JOYSTICK_HINT) from None
        try:
            device: Any = evdev.InputDevice(path)
        except OSError as exc:
            raise ChassisError(f"cannot open --joystick {path}: {exc.strerror}") from None
        try:
            caps: dict[int, list[Any]] = device.capabilities(absinfo=True)
            axes = dict(caps.get(EV_ABS, []))
            missing = [
                code_name(a, ABS_CODES)
                for a in (mapping.linear_axis, mapping.angular_axis)
                if a not in axes
            ]
            if mapping.enable_button not in caps.get(EV_KEY, []):
                missing.append(code_name(mapping.enable_button, BTN_CODES))
            if missing:
                raise ChassisError(f"--joystick {path} ({device.name}) has no {', '.join(missing)}")
            ranges = {code: AxisRange(info.min, info.max) for code, info in axes.items()}
            values = {code: int(info.value) for code, info in axes.items()}
            self.state = JoyState(mapping, ranges, values, now)
        except ValueError as exc:
            device.close()
            raise ChassisError(f"--joystick {path}: {exc}") from None
        except BaseException:
            device.close()
            raise
        self.path = path
        #: The device's name, as it reports it.
        self.name: str = device.name
        #: Set when the pad is gone (unplugged): why, in words.
        self.gone: str | None = None
        self._device = device
        self._loop: asyncio.AbstractEventLoop | None = None

    def start(self, clock: Callable[[], float], changed: Callable[[], None]) -> None:
        """Read from the running loop: each batch of events is fed to `state`
        with ``clock()``'s time, then ``changed()`` is called (also when it is gone)."""
        self._loop = asyncio.get_running_loop()
        fd = self._device.fd

        def readable() -> None:
            try:
                events = list(self._device.read())
            except BlockingIOError:
                return
            except OSError as exc:
                self._stop_reading()
                gone = "unplugged" if exc.errno == errno.ENODEV else exc.strerror
                self.gone = f"--joystick {self.path}: {gone}"
            else:
                now = clock()
                for ev in events:
                    self.state.event(ev.type, ev.code, ev.value, now)
            changed()

        self._loop.add_reader(fd, readable)

    def _stop_reading(self) -> None:
        if self._loop is not None:
            self._loop.remove_reader(self._device.fd)
            self._loop = None

    def close(self) -> None:
        """Stop reading and close the device."""
        self._stop_reading()
        self._device.close()
