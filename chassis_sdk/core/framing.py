"""The incremental framing core shared by every decoder in this package.

Why it is shaped this way
-------------------------
A serial port hands us bytes in arbitrary chunks: one byte, half a frame, ten frames,
and on a noisy line, garbage anywhere. Both protocols frame messages the same way: a
two-byte head, a header from which the frame's length can be worked out, and a check.
What differs is how the length is found and how the frame is checked, so the scanning
loop lives here once and each protocol supplies a single ``_try_frame`` method.

The loop keeps one rule that makes it robust: a candidate frame that fails (bad tail,
bad checksum, impossible length) gives up **only its first byte**. Scanning resumes at
the next head *inside the same buffer*, so a false head in the noise can never swallow
a good frame that starts within the bytes it claimed. The price is that a false head
with a long claimed length delays (never loses) the frames behind it until enough bytes
have arrived to reject it; frame lengths are bounded by the one-byte length fields, so
that delay is bounded too.

The buffer never holds more than one incomplete candidate after ``feed`` returns (at
most the largest frame, 259 bytes, plus the few bytes a codec with an alignment rule
may look past it), or a possible first head byte: its size is bounded without any explicit limit,
whatever the input.

Nothing here does I/O or reads a clock: the caller passes a timestamp in.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Generic, TypeVar

__all__ = [
    "INVALID",
    "NEED_DATA",
    "Column",
    "DecoderStats",
    "FrameDecoder",
    "FrameLayout",
    "FrameTable",
    "Parser",
    "byte_sum",
]

T = TypeVar("T")

#: What every codec's per-frame-type parser looks like: it gets (buffer, offset of the
#: frame's *data*, data length, timestamp) and returns a message, or ``None`` if the
#: content is invalid although the frame checked out (counted as malformed). Header
#: fields a parser needs sit at fixed negative offsets from the data.
Parser = Callable[[bytes | bytearray, int, int, float], Any]
#: What a codec knows of each frame type it accepts: type (or id) -> (the value the
#: frame's length field must hold, or 0 for a type of variable length; its parser).
#: The length field is the protocol's own: it may count the whole frame or the data.
FrameTable = dict[int, tuple[int, Parser]]

#: ``_try_frame`` result: the candidate at this offset is incomplete; wait for more bytes.
NEED_DATA = 0
#: ``_try_frame`` result: the candidate at this offset is not a frame; skip one byte.
INVALID = -1

#: ``byte_sum(data, 0) & 0xFFFF`` is ``sum(data)`` for any frame of either protocol, at half
#: the cost: it is Adler-32, whose low 16 bits are the byte sum modulo 65521 (from 0);
#: a frame has at most 255 bytes, whose sum (at most 65,025) never reaches the modulus.
#: Both protocols' checks are byte sums (A: 16-bit, B: 8-bit), so both use it.
byte_sum = zlib.adler32


@dataclass(slots=True)
class DecoderStats:
    """Counters of what a decoder has seen and dropped.

    Attributes:
        bytes_received: Every byte fed in.
        frames: Frames decoded into messages.
        bytes_dropped: Bytes skipped as noise (garbage, false heads, rejected frames).
        checksum_errors: Candidates with a plausible header and tail whose check failed.
        malformed_frames: Frames that passed the check but whose content was invalid
            (an unknown drive mode, log text that is not UTF-8, ...).
        length_mismatches: Frames accepted although their length byte was wrong (the
            vendor's 0x89 example has this defect; real firmware may too).
        misaligned_frames: Candidates that passed the check but that the bytes after
            them showed to be shifted by a lost or inserted byte (a protocol whose
            one-byte check lets 1 in 256 corrupted frames through).
    """

    bytes_received: int = 0
    frames: int = 0
    bytes_dropped: int = 0
    checksum_errors: int = 0
    malformed_frames: int = 0
    length_mismatches: int = 0
    misaligned_frames: int = 0

    def as_dict(self) -> dict[str, int]:
        """Return the counters as a plain ``dict`` (handy for logging and JSON)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True)
class FrameLayout:
    """A protocol's framing rules as data, for decoding a whole capture with arrays
    (`chassis_sdk.recording.columns`). It must say exactly what the codec's
    ``_try_frame`` does; a test holds the two to the same frames.

    A frame starts with the decoder's head; its type is the byte at ``type_at`` and its length
    byte at ``length_at``. A type whose table size is 0 has a variable size: the frame
    is ``length + size_of_length`` bytes, and needs ``length >= min_length``. Otherwise
    the table size is the frame size (``fixed_is_length`` False: the length byte is not
    checked), or the value the length byte must have (``fixed_is_length`` True; the
    frame is then ``length + size_of_length`` bytes). Nothing is decided before
    ``header`` bytes are there. The check is the sum of the bytes from ``sum_from``
    (after the head's start) up to the check field, modulo 256 or 65536 for a
    ``check_size`` of 1 or 2 (little-endian); ``tail`` closes the frame. A parser gets
    the data at ``data_at`` and ``size - overhead`` bytes of it. ``no_head_inside``:
    a frame is refused while a plausible head (head, known type, possible length)
    starts inside it, or may start at its last byte (a codec's alignment rule).
    """

    type_at: int
    length_at: int
    header: int
    fixed_is_length: bool
    size_of_length: int
    min_length: int
    sum_from: int
    check_size: int
    tail: bytes
    data_at: int
    overhead: int
    no_head_inside: bool = False


@dataclass(frozen=True, slots=True)
class Column:
    """One field of a fixed-size frame, read into an array by
    `chassis_sdk.recording.columns`: ``name`` (the flattened name a CSV export uses,
    e.g. ``wheels.front_left``), the struct code of the little-endian field (``"h"``,
    ``"H"``, ``"B"``, ...) at ``at`` bytes from the frame's data (negative: in the
    header), and ``divisor``: the value in SI units is the raw number divided by it
    (``None``: kept as the raw integer, for codes and flags)."""

    name: str
    at: int
    code: str
    divisor: float | None = 1.0


class FrameDecoder(Generic[T]):
    """Incremental decoder: ``feed`` bytes in any chunking, get complete messages out.

    Subclasses set ``_head`` (the two head bytes) and implement `_try_frame`.
    """

    _head: bytes = b""
    #: The frame types this decoder accepts (subclasses that use a table set it).
    _table: ClassVar[FrameTable] = {}
    #: The framing as data, for decoding whole captures into arrays (None: not described).
    layout: ClassVar[FrameLayout | None] = None
    #: The fields of the frame types decoded into arrays, by type: ``(message class
    #: name, columns)``. Such a type's parser must accept every frame that checks out.
    columns: ClassVar[dict[int, tuple[str, tuple[Column, ...]]]] = {}

    __slots__ = ("_buf", "stats")

    def __init__(self) -> None:
        self._buf = bytearray()
        self.stats = DecoderStats()

    def reset(self) -> None:
        """Forget any partial frame (after a reconnect, for example). Stats are kept."""
        self._buf.clear()

    @property
    def buffered(self) -> int:
        """How many bytes are held waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview, timestamp: float = 0.0) -> list[T]:
        """Consume ``data`` and return every message completed by it, in wire order.

        Args:
            data: The bytes as they arrived; any chunking, garbage included.
            timestamp: Time of receipt, stored on timestamped messages. The decoder never
                reads a clock itself; the link passes ``time.monotonic()``.

        Returns:
            The decoded messages (possibly none). Never raises for any input.
        """
        stored = self._buf
        # With nothing held over (the usual case), parse the chunk where it lies and
        # keep only its unfinished tail; otherwise append it to what is held.
        buf: bytes | bytearray
        if stored:
            stored += data
            buf = stored
        else:
            buf = data if type(data) is bytes else bytes(data)
        stats = self.stats
        n = len(buf)
        stats.bytes_received += len(data)
        out: list[T] = []
        head = self._head
        pos = 0
        dropped = 0
        while pos < n:
            start = buf.find(head, pos)
            if start < 0:
                # Keep a trailing first head byte: its partner may be in the next chunk.
                keep = n - 1 if buf[n - 1] == head[0] else n
                dropped += keep - pos
                pos = keep
                break
            dropped += start - pos
            consumed = self._try_frame(buf, start, n, out, timestamp)
            if consumed > 0:
                pos = start + consumed
            elif consumed == NEED_DATA:
                pos = start
                break
            else:
                dropped += 1
                pos = start + 1
        if buf is stored:
            if pos:
                del stored[:pos]
        elif pos < n:
            stored += buf[pos:]
        if dropped:
            stats.bytes_dropped += dropped
        stats.frames += len(out)
        return out

    def _try_frame(
        self, buf: bytes | bytearray, start: int, end: int, out: list[T], ts: float
    ) -> int:
        """Try to decode one frame whose head is at ``buf[start]``.

        Args:
            buf: The buffer; valid bytes are ``buf[start:end]``.
            start: Offset of the head.
            end: End of the valid bytes.
            out: Append each decoded message here.
            ts: Timestamp to store on the message.

        A decoder may consume several back-to-back frames in one call; every message
        it appends is one frame (the caller counts them).

        Returns:
            The bytes consumed (one frame or more) if any were, `NEED_DATA` if the
            candidate is still incomplete, `INVALID` if it is not a frame.
        """
        raise NotImplementedError
