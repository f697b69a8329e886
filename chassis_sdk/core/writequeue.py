"""What a link holds while its port cannot take bytes: the decisions of the write
path, sans-IO (no asyncio, no clock of its own: the time is given).

The `Link` does the writing; this class decides what
waits, what is discarded and what goes next:

* a **velocity frame is state, not a queue**: only the newest waits (the one it
  replaces is discarded and counted), and one whose command has expired by the time
  the port can take it is dropped and counted, never sent;
* other frames (requests, e-stops) wait in order, up to `QUEUE_LIMIT` bytes;
  past that a frame is discarded and counted;
* once velocity is closed off (`WriteQueue.close_velocity`) no velocity frame
  but the final zero is taken, and when a closing link discards every stale frame
  (`WriteQueue.discard_stale`) the final zero is what remains.
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["QUEUE_LIMIT", "WriteQueue"]

#: Bytes of non-velocity frames held while the port cannot take them (requests and
#: commands are at most a few dozen bytes each; past this the device is not reading).
QUEUE_LIMIT = 1024


class WriteQueue:
    """The frames a link holds, under a discipline that knows what they are.

    Frames come out in this order: every held non-velocity frame, oldest first, then
    the held velocity frame. `peek` says what is next, `pop` that the port
    took it.

    Args:
        limit: Bytes of non-velocity frames `push` holds at most.
    """

    __slots__ = (
        "_frames",
        "_velocity",
        "discarded",
        "held_bytes",
        "limit",
        "velocity_closed",
        "zero",
    )

    def __init__(self, limit: int = QUEUE_LIMIT) -> None:
        self.limit = limit
        self._frames: deque[bytes] = deque()
        #: Bytes of the non-velocity frames held.
        self.held_bytes = 0
        self._velocity: tuple[bytes, float] | None = None  # newest held frame, its expiry
        #: True once :meth:`close_velocity` has been called: no velocity frame is taken.
        self.velocity_closed = False
        #: The final zero, once :meth:`close_velocity` recorded it.
        self.zero: bytes | None = None
        #: Frames discarded: velocity frames replaced by newer ones or expired while
        #: they waited, frames over the limit, and whatever was dropped with the rest.
        self.discarded = 0

    # --- what is held ------------------------------------------------------------------

    @property
    def frames(self) -> tuple[bytes, ...]:
        """The non-velocity frames held, oldest first."""
        return tuple(self._frames)

    @property
    def velocity(self) -> tuple[bytes, float] | None:
        """The velocity frame held and its expiry, or ``None``."""
        return self._velocity

    @property
    def waiting(self) -> bool:
        """True while a non-velocity frame is held (a velocity frame must wait behind
        it)."""
        return bool(self._frames)

    @property
    def holds(self) -> bool:
        """True while any frame is held."""
        return bool(self._frames) or self._velocity is not None

    # --- taking frames -----------------------------------------------------------------

    def push(self, frame: bytes) -> bool:
        """Hold a non-velocity frame behind the others, within the limit.

        Returns:
            False if it would take the held bytes past the limit: it is then discarded
            and counted.
        """
        if self.held_bytes + len(frame) > self.limit:
            self.discarded += 1
            return False
        self._frames.append(frame)
        self.held_bytes += len(frame)
        return True

    def hold(self, frame: bytes) -> None:
        """Hold a non-velocity frame the port has just refused, whatever the limit (it
        was going out at once: nothing else was held)."""
        self._frames.append(frame)
        self.held_bytes += len(frame)

    def put_velocity(self, frame: bytes, expires: float = math.inf) -> bool:
        """Hold a velocity frame in place of the one held (which is discarded and
        counted); it must not be sent after ``expires``.

        Returns:
            False if velocity is closed off: nothing changes.
        """
        if self.velocity_closed:
            return False
        if self._velocity is not None:
            self.discarded += 1
        self._velocity = (frame, expires)
        return True

    def close_velocity(self, zero: bytes) -> None:
        """Record ``zero`` as the final velocity frame and take no velocity frame from
        now on (the caller has written or held ``zero`` already)."""
        self.velocity_closed = True
        self.zero = zero

    # --- giving frames out -------------------------------------------------------------

    def peek(self, now: float) -> bytes | None:
        """The frame to send next, or ``None`` if nothing is held.

        A held velocity frame whose expiry has passed at ``now`` is dropped (and
        counted) here instead of being given out.
        """
        if self._frames:
            return self._frames[0]
        held = self._velocity
        if held is None:
            return None
        frame, expires = held
        if now > expires:
            self._velocity = None
            self.discarded += 1  # its command ran out while it waited
            return None
        return frame

    def pop(self) -> None:
        """The port took the frame `peek` gave out: stop holding it."""
        if self._frames:
            self.held_bytes -= len(self._frames.popleft())
        else:
            self._velocity = None

    # --- discarding --------------------------------------------------------------------

    def drop_all(self) -> int:
        """Discard and count everything held; return how many frames that was."""
        dropped = len(self._frames) + (self._velocity is not None)
        self.discarded += dropped
        self._frames.clear()
        self.held_bytes = 0
        self._velocity = None
        return dropped

    def discard_stale(self, flushed: bool) -> bool:
        """The link is closing and the device is not reading: discard every frame held,
        but keep the final zero.

        Args:
            flushed: The port's own output buffer was discarded too (a serial port's
                kernel queue), so the zero may have gone with it even if it had left
                the link.

        Returns:
            True if the final zero is held again (whole, never expiring), to be sent
            as the last frame; it is not counted as discarded if it was held already.
        """
        held_zero = self._velocity is not None and self.velocity_closed
        self.drop_all()
        if self.zero is not None and (held_zero or flushed):
            self.discarded -= held_zero
            self._velocity = (self.zero, math.inf)
            return True
        return False
