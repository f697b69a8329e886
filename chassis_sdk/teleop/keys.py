"""The key state machine of ``chassis-sdk teleop``: bytes from a terminal in, what to
do to the robot out. Sans-IO: no asyncio, no terminal, no clock (every call takes
``now``), so every timing is tested with numbers.

Why it is shaped so
-------------------
A terminal sends a byte sequence when a key goes down and then, while the key is held,
the same sequence again by *autorepeat*: after an initial delay (X11's default 660 ms,
GNOME, KDE, Windows and macOS about 500-600 ms, the Linux console 250 ms), then at the
repeat rate (25-33 Hz on desktops, 11 Hz on the console). It never sends a key-up. So
a key counts as held until no repeat of it has arrived for a *key timeout*, and then as
released (the robot is stopped). That timeout adapts:

- **Before the first repeat** of a press, it is the initial delay plus a margin:
  ``--key-timeout`` (default `KEY_TIMEOUT`, 0.75 s, which covers X11's 660 ms)
  until one hold has shown the terminal's delay; from then on
  ``min(key_timeout, 1.25 * delay + 0.05)`` with ``delay`` the longest initial delay
  seen (0.675 s for a 500 ms desktop, 0.36 s on the console). A delay counts as seen
  only when the repeats that follow it are fast (under 0.1 s and under half of it), so
  a double tap is not mistaken for one. A delay longer than the timeout (a stutter: the
  press was released, then its first repeat came as a new press, quickly followed by
  more) is learned too, so a terminal stutters at most once per longer delay.
- **While repeats arrive** (from a press's third arrival), it is
  ``clamp(3 * gap, 0.15, key_timeout)`` with ``gap`` the longest of this hold's last
  four intervals between repeats: 0.15 s at 25-30 Hz, 0.28 s on the console (11 Hz).
  Three intervals and that floor, so a repeat up to some 110 ms late (SSH over Wi-Fi, a
  busy computer) does not stop the robot; a 0.1 s floor made a held key stutter on a
  loaded machine.

So a released key stops the robot within that timeout of its last arrival (no tick
adds to it: `KeyTeleop.deadline` is when to look again). A key timeout shorter
than the terminal's initial delay makes a held key stutter once at the start (it stops,
then the first repeat drives again): safe, but pass a larger ``--key-timeout``.

Terminals repeat only the last key pressed: pressing another direction replaces the
held one (there are no diagonals), and pressing ``+``/``-`` while driving ends the held
key's repeats, so the robot stops until the direction is pressed again.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass, field

from ..core.validation import check_real

__all__ = [
    "KEY_HELP",
    "KEY_TIMEOUT",
    "MAX_KEY_TIMEOUT",
    "REPEAT_FLOOR",
    "Effect",
    "Key",
    "KeyDecoder",
    "KeyTeleop",
]

#: Default key timeout before the first autorepeat (s): above X11's 660 ms delay.
KEY_TIMEOUT = 0.75
#: The longest key timeout taken (s): a tap drives for up to the key timeout, so a typo
#: (7.5 for 0.75) must not mean seconds of motion.
MAX_KEY_TIMEOUT = 2.0
#: The shortest key timeout while repeats arrive (s).
REPEAT_FLOOR = 0.15
#: While repeats arrive the timeout is this many repeat intervals.
REPEATS = 3
#: How many recent repeat intervals the timeout follows (it takes the longest).
GAPS = 4
#: A learned initial delay is stretched by this factor plus :data:`DELAY_MARGIN`.
DELAY_FACTOR = 1.25
DELAY_MARGIN = 0.05
#: Repeats at least this fast (s) after a long first gap prove it was the initial delay.
FAST_REPEAT = 0.1
#: The speed scale's step and bounds (percent of ``--max-linear``/``--max-angular``).
SPEED_STEP = 10
SPEED_MIN = 10
SPEED_MAX = 100

#: Printed once when teleop starts.
KEY_HELP = "arrows/WASD drive (hold), +/- speed, space stop, e e-stop, r release e-stop, q quit"


class Key(enum.Enum):
    """What a key means to teleop."""

    FORWARD = "forward"  #: Up arrow, w, W.
    BACKWARD = "backward"  #: Down arrow, s, S.
    LEFT = "left"  #: Left arrow, a, A: turn left (positive angular).
    RIGHT = "right"  #: Right arrow, d, D.
    FASTER = "faster"  #: ``+`` or ``=`` (the same key unshifted).
    SLOWER = "slower"  #: ``-`` or ``_``.
    STOP = "stop"  #: Space.
    ESTOP = "estop"  #: e, E.
    RELEASE = "release"  #: r, R: release the e-stop.
    QUIT = "quit"  #: q, Q, Ctrl-C, Ctrl-D.


#: (linear sign, angular sign) of each direction key.
DIRECTIONS: dict[Key, tuple[int, int]] = {
    Key.FORWARD: (1, 0),
    Key.BACKWARD: (-1, 0),
    Key.LEFT: (0, 1),
    Key.RIGHT: (0, -1),
}

_BYTES: dict[int, Key] = {
    **{ord(c): Key.FORWARD for c in "wW"},
    **{ord(c): Key.BACKWARD for c in "sS"},
    **{ord(c): Key.LEFT for c in "aA"},
    **{ord(c): Key.RIGHT for c in "dD"},
    **{ord(c): Key.FASTER for c in "+="},
    **{ord(c): Key.SLOWER for c in "-_"},
    ord(" "): Key.STOP,
    **{ord(c): Key.ESTOP for c in "eE"},
    **{ord(c): Key.RELEASE for c in "rR"},
    **{ord(c): Key.QUIT for c in "qQ"},
    0x03: Key.QUIT,  # Ctrl-C (the terminal sends it as a byte: ISIG is off)
    0x04: Key.QUIT,  # Ctrl-D
}
#: The final byte of an arrow's CSI (``ESC [ A``) or SS3 (``ESC O A``) sequence.
_ARROWS = {ord("A"): Key.FORWARD, ord("B"): Key.BACKWARD, ord("C"): Key.RIGHT, ord("D"): Key.LEFT}
_ESC = 0x1B


class KeyDecoder:
    """Terminal bytes to `Key` s, whatever the reads cut them into.

    Arrows come as ``ESC [ A`` (normal mode, with modifiers ``ESC [ 1 ; 2 A`` taken as
    the plain arrow) or ``ESC O A`` (application mode); a sequence split across reads
    is kept until its end arrives. Other escape sequences (function keys, ...) and
    unknown bytes are skipped; an ``ESC`` followed by something that starts no
    sequence (Alt-w) is dropped and the byte after it read as itself.
    """

    def __init__(self) -> None:
        self._pending = bytearray()

    def feed(self, data: bytes) -> list[Key]:
        """The keys that ``data`` completes, in order."""
        buf = self._pending + data
        keys: list[Key] = []
        i = 0
        n = len(buf)
        while i < n:
            b = buf[i]
            if b != _ESC:
                key = _BYTES.get(b)
                if key is not None:
                    keys.append(key)
                i += 1
                continue
            if i + 1 >= n:
                break  # a lone ESC so far: wait for what follows
            intro = buf[i + 1]
            if intro == ord("O"):  # SS3: one final byte
                if i + 2 >= n:
                    break
                arrow = _ARROWS.get(buf[i + 2])
                if arrow is not None:
                    keys.append(arrow)
                i += 3
                continue
            if intro != ord("["):
                i += 1  # not a sequence: drop the ESC, read the byte as itself
                continue
            j = i + 2  # CSI: parameters and intermediates (0x20-0x3F), then a final byte
            while j < n and 0x20 <= buf[j] <= 0x3F:
                j += 1
            if j >= n:
                if j - i > 16:  # a runaway sequence: give up on it
                    i = j
                    continue
                break
            if 0x40 <= buf[j] <= 0x7E:
                arrow = _ARROWS.get(buf[j])
                if arrow is not None:
                    keys.append(arrow)
                i = j + 1
            else:  # not a CSI after all
                i += 2
        self._pending = bytearray(buf[i:])
        return keys


class Effect(enum.Enum):
    """What the I/O around `KeyTeleop` must do next."""

    DRIVE = "drive"  #: Write :attr:`KeyTeleop.velocity` (it changed, or was refreshed).
    STOP = "stop"  #: Write zero.
    ESTOP = "estop"  #: Engage the emergency stop (zero included).
    RELEASE = "release"  #: Release the emergency stop (nothing moves).
    QUIT = "quit"  #: Write zero and end.


@dataclass
class _Hold:
    """The direction key held now: its arrivals and their gaps."""

    key: Key
    first: float
    last: float
    arrivals: int = 1
    first_gap: float = 0.0
    #: The same key was released by its timeout this long before this press: the
    #: initial delay, if fast repeats follow (the timeout was too short: a stutter).
    stutter: float = 0.0
    gaps: deque[float] = field(default_factory=lambda: deque(maxlen=GAPS))


class KeyTeleop:
    """Keys in, velocity commands out; see the module's docstring for the timing.

    Args:
        max_linear: Linear speed (m/s) at 100 %.
        max_angular: Angular speed (rad/s) at 100 %.
        key_timeout: The key timeout before the first autorepeat, and the ceiling of
            every key timeout (s).
        speed: Starting speed scale, a fraction of the maxima (0 to 1], kept to whole
            percent; ``+``/``-`` step it by 10 points within 10-100 %.

    Raises:
        ValueError: A bound that is not a positive number, a ``speed`` out of range.
    """

    def __init__(
        self,
        *,
        max_linear: float,
        max_angular: float,
        key_timeout: float = KEY_TIMEOUT,
        speed: float = 0.3,
    ) -> None:
        self.max_linear = check_real(max_linear, "max_linear", low=0, low_open=True)
        self.max_angular = check_real(max_angular, "max_angular", low=0, low_open=True)
        self.key_timeout = check_real(
            key_timeout, "key_timeout", low=0, low_open=True, high=MAX_KEY_TIMEOUT, unit="s"
        )
        speed = check_real(speed, "speed", low=0, high=1, low_open=True)
        #: The speed scale, percent.
        self.percent = max(1, round(speed * 100))
        #: The engaged e-stop: direction keys are ignored until ``r``.
        self.estopped = False
        #: ``q`` or Ctrl-C was pressed.
        self.quit = False
        self._decoder = KeyDecoder()
        self._hold: _Hold | None = None
        self._delay: float | None = None  # the longest initial delay seen
        self._tapped: tuple[Key, float] | None = None  # a press released unrepeated

    # --- reading ---------------------------------------------------------------------------------

    @property
    def held(self) -> Key | None:
        """The direction key held now, or ``None``."""
        return None if self._hold is None else self._hold.key

    @property
    def velocity(self) -> tuple[float, float]:
        """The command now: ``(linear m/s, angular rad/s)``, zeros when no key is held."""
        if self._hold is None:
            return (0.0, 0.0)
        lin, ang = DIRECTIONS[self._hold.key]
        scale = self.percent / 100
        return (lin * self.max_linear * scale + 0.0, ang * self.max_angular * scale + 0.0)

    @property
    def initial_timeout(self) -> float:
        """The key timeout of a press before its first autorepeat (s)."""
        if self._delay is None:
            return self.key_timeout
        return min(self.key_timeout, DELAY_FACTOR * self._delay + DELAY_MARGIN)

    @property
    def timeout(self) -> float | None:
        """The key timeout of the held key now (s), or ``None`` when none is held."""
        hold = self._hold
        if hold is None:
            return None
        if not hold.gaps:  # before its first repeat interval
            return self.initial_timeout
        return min(max(REPEATS * max(hold.gaps), REPEAT_FLOOR), self.key_timeout)

    @property
    def deadline(self) -> float | None:
        """When the held key counts as released unless it repeats (``now`` units), or
        ``None``: the time to call `poll` next."""
        hold = self._hold
        timeout = self.timeout
        return None if hold is None or timeout is None else hold.last + timeout

    # --- input ------------------------------------------------------------------------------------

    def feed(self, data: bytes, now: float) -> list[Effect]:
        """Bytes read from the terminal at ``now``: what to do, in order (a release
        that was due before ``now`` comes first)."""
        effects = self.poll(now)
        for key in self._decoder.feed(data):
            effects.extend(self.key(key, now))
        return effects

    def poll(self, now: float) -> list[Effect]:
        """``[Effect.STOP]`` if the held key's timeout has passed at ``now`` (it was
        released), else nothing."""
        deadline = self.deadline
        hold = self._hold
        if hold is None or deadline is None or now < deadline:
            return []
        self._hold = None
        if hold.arrivals == 1:  # never repeated: a tap, or a delay longer than the timeout
            self._tapped = (hold.key, hold.first)
        return [Effect.STOP]

    def key(self, key: Key, now: float) -> list[Effect]:
        """One decoded key at ``now``."""
        if key is Key.QUIT:
            self.quit = True
            self._hold = None
            return [Effect.QUIT]
        if key is Key.STOP:
            self._hold = None
            return [Effect.STOP]
        if key is Key.ESTOP:
            self._hold = None
            self.estopped = True
            return [Effect.ESTOP]
        if key is Key.RELEASE:
            if not self.estopped:
                return []
            self.estopped = False
            return [Effect.RELEASE]
        if key in (Key.FASTER, Key.SLOWER):
            step = SPEED_STEP if key is Key.FASTER else -SPEED_STEP
            percent = min(max(self.percent + step, SPEED_MIN), SPEED_MAX)
            if percent == self.percent:
                return []
            self.percent = percent
            return [Effect.DRIVE] if self._hold is not None else []
        if self.estopped:
            return []
        return self._direction(key, now)

    def _direction(self, key: Key, now: float) -> list[Effect]:
        hold = self._hold
        if hold is None or hold.key is not key:  # a press (or a new key replacing one)
            self._hold = _Hold(key, now, now)
            tapped, self._tapped = self._tapped, None
            if hold is None and tapped is not None and tapped[0] is key:
                self._hold.stutter = now - tapped[1]
            return [Effect.DRIVE]
        gap = now - hold.last
        hold.arrivals += 1
        hold.last = now
        if hold.arrivals == 2:
            hold.first_gap = gap  # the initial delay, if fast repeats follow
            if hold.stutter and gap < FAST_REPEAT:
                self._delay = max(self._delay or 0.0, hold.stutter)
        else:
            hold.gaps.append(gap)
            if hold.arrivals == 3 and gap < FAST_REPEAT and gap < hold.first_gap / 2:
                self._delay = max(self._delay or 0.0, hold.first_gap)
        return [Effect.DRIVE]
