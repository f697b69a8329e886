"""A whole capture decoded at once into arrays, one per field, in SI units (numpy).

Why it exists
-------------
The decoders in `.framing` serve a live link: bytes come in chunks and each frame
becomes an object, about 3 µs apiece. A recorded hour is 180,000 frames that are all
there already, and analysis (plots, CSV, numpy and pandas users) wants a column per
field, not 180,000 objects. This module finds every frame of the whole byte string with
array operations and reads the fields of the high-rate frame types straight into
arrays; the rare types go through the codec's own parser, one object each.

It finds the frames the streaming decoder finds, by the same rules, given as data by
the codec (`FrameLayout`):

* a candidate is a head whose type is known, whose length is possible, whose frame fits
  in the data, whose check and tail hold, whose parser accepts it, and (protocol B) in
  which no plausible head starts;
* candidates are taken from the left; one that starts inside a frame already taken was
  never looked at by the scanner, so it is not a frame;
* a candidate the end of the data cuts off ends the decoding there, as the streaming
  decoder waits for bytes that never come.

Decisions use only the bytes, never where a chunk ended, so chunking cannot change
which frames come out (the streaming decoder promises the same). The time of a frame is
that of the chunk holding its last byte. The streaming decoder can emit a frame later,
when it must wait for more bytes to decide a candidate before or around it (a false
head claiming a long frame; protocol B, a frame ending in ``FE``): never earlier.

It knows no protocol: the codec says how it frames (``layout``) and which fields of
which types become columns (``columns``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..core.framing import Column, FrameDecoder, FrameLayout

__all__ = ["Columns", "decode_columns", "decode_joined"]

_INVALID, _VALID, _NEED = 0, 1, 2
_Ints = npt.NDArray[np.int64]


@dataclass
class Columns:
    """What [`decode_columns`][chassis_sdk.recording.columns.decode_columns] found.

    Attributes:
        tables: By message class name (``"Telemetry"``, ``"ImuSample"``): column name ->
            array, ``t`` (seconds, the capture's clock) first, then the fields in SI
            units, nested ones flattened as in a CSV export (``wheels.front_left``);
            codes and flags as raw integers.
        messages: ``(t, message)`` of every other frame, in wire order.
        frames: Frames decoded, of either kind.
        bytes: Bytes read.
        bytes_dropped: Bytes that were in no frame.
    """

    tables: dict[str, dict[str, npt.NDArray[Any]]] = field(default_factory=dict)
    messages: list[tuple[float, object]] = field(default_factory=list)
    frames: int = 0
    bytes: int = 0
    bytes_dropped: int = 0

    def __getitem__(self, name: str) -> dict[str, npt.NDArray[Any]]:
        """``columns["Telemetry"]["linear"]``; a type with no frame has no table."""
        return self.tables[name]


def decode_columns(chunks: Iterable[tuple[float, bytes]], decoder: FrameDecoder[Any]) -> Columns:
    """Decode a capture's ``(t, bytes)`` chunks with ``decoder``'s framing, into columns.

    Raises:
        ValueError: The decoder's class does not describe its framing (``layout``).
    """
    times: list[float] = []
    parts: list[bytes] = []
    for t, data in chunks:
        if data:
            times.append(t)
            parts.append(data)
    return decode_joined(b"".join(parts), times, [len(p) for p in parts], decoder)


def decode_joined(
    raw: bytes, times: Sequence[float], sizes: Sequence[int], decoder: FrameDecoder[Any]
) -> Columns:
    """`decode_columns` of chunks already joined: ``raw`` is every chunk's bytes
    in order, chunk ``i`` arrived at ``times[i]`` and holds ``sizes[i]`` bytes."""
    cls = type(decoder)
    layout = cls.layout
    if layout is None:
        raise ValueError(f"{cls.__name__} has no layout: decode it frame by frame")
    result = Columns(bytes=len(raw))
    if not raw:
        return result
    ends = np.cumsum(np.asarray(sizes, dtype=np.int64))
    if int(ends[-1]) != len(raw):
        raise ValueError(f"the chunk sizes add up to {int(ends[-1])}, not {len(raw)} bytes")
    buf = np.frombuffer(raw, dtype=np.uint8)
    table = cls._table
    starts, stops, kinds = _frames(buf, cls._head, layout, table, cls.columns, raw)
    chunk_of = np.searchsorted(ends, stops - 1, side="right")
    frame_t = np.asarray(times, dtype=np.float64)[chunk_of]
    result.frames = len(starts)
    result.bytes_dropped = len(raw) - int((stops - starts).sum())
    for kind, (name, columns) in cls.columns.items():
        mine = kinds == kind
        if mine.any():
            result.tables[name] = _read_columns(buf, starts[mine], frame_t[mine], layout, columns)
    rare = np.flatnonzero(~np.isin(kinds, list(cls.columns)))
    for i in rare.tolist():
        start, t = int(starts[i]), float(frame_t[i])
        size = int(stops[i]) - start
        parser = table[int(kinds[i])][1]
        result.messages.append((t, parser(raw, start + layout.data_at, size - layout.overhead, t)))
    return result


def _frames(
    buf: npt.NDArray[np.uint8],
    head: bytes,
    layout: FrameLayout,
    table: dict[int, tuple[int, Any]],
    columns: dict[int, Any],
    raw: bytes,
) -> tuple[_Ints, _Ints, _Ints]:
    """(starts, stops, types) of the frames the streaming decoder would find."""
    n = len(buf)
    h0, h1 = head
    heads = np.flatnonzero((buf[:-1] == h0) & (buf[1:] == h1)).astype(np.int64)
    status = np.full(len(heads), _INVALID, dtype=np.int8)
    # Per type: -1 unknown, 0 variable, else the fixed frame size (or length byte).
    fixed = np.full(256, -1, dtype=np.int64)
    for frame_type, (table_size, _) in table.items():
        fixed[frame_type] = table_size
    has_header = heads + layout.header <= n
    status[~has_header] = _NEED
    h = heads[has_header]
    kind = buf[h + layout.type_at].astype(np.int64)
    length = buf[h + layout.length_at].astype(np.int64)
    entry = fixed[kind]
    known = entry >= 0
    variable = entry == 0
    if layout.fixed_is_length:
        length_ok = np.where(variable, length >= layout.min_length, length == entry)
        size = length + layout.size_of_length
    else:
        length_ok = np.where(variable, length >= layout.min_length, True)
        size = np.where(variable, length + layout.size_of_length, entry)
    plausible = known & length_ok
    stop = h + size
    fits = stop <= n
    sub = np.full(len(h), _INVALID, dtype=np.int8)
    sub[plausible & ~fits] = _NEED
    check = plausible & fits
    c = np.flatnonzero(check)
    cs, cstop = h[c], stop[c]
    ok = np.ones(len(c), dtype=bool)
    tail_at = cstop - len(layout.tail)
    for i, byte in enumerate(layout.tail):
        ok &= buf[tail_at + i] == byte
    # Running byte sums, wrapping at 2**32: a difference of two is still a window's sum
    # modulo 2**32, and the checks need it modulo 2**16 or 2**8 only.
    sums = np.empty(n + 1, dtype=np.uint32)
    sums[0] = 0
    np.cumsum(buf, dtype=np.uint32, out=sums[1:])
    check_at = tail_at - layout.check_size
    total = sums[check_at] - sums[cs + layout.sum_from]
    if layout.check_size == 2:
        ok &= (total & 0xFFFF) == (
            buf[check_at].astype(np.int64) | buf[check_at + 1].astype(np.int64) << 8
        )
    else:
        ok &= (total & 0xFF) == buf[check_at]
    good = np.zeros(len(h), dtype=bool)
    good[c[ok]] = True
    # Types whose parser may refuse a frame that checks out: ask it.
    for i in np.flatnonzero(good & ~np.isin(kind, list(columns))).tolist():
        start, k = int(h[i]), int(kind[i])
        if table[k][1](raw, start + layout.data_at, int(size[i]) - layout.overhead, 0.0) is None:
            good[i] = False
    sub[good] = _VALID
    if layout.no_head_inside:
        sub = _refuse_misaligned(buf, head, layout, fixed, h, stop, plausible, sub)
    status[has_header] = sub
    all_stops = np.zeros(len(heads), dtype=np.int64)
    all_stops[has_header] = stop
    all_kinds = np.zeros(len(heads), dtype=np.int64)
    all_kinds[has_header] = kind
    return _take_from_the_left(heads, all_stops, all_kinds, status)


def _refuse_misaligned(
    buf: npt.NDArray[np.uint8],
    head: bytes,
    layout: FrameLayout,
    fixed: _Ints,
    h: _Ints,
    stop: _Ints,
    plausible: npt.NDArray[np.bool_],
    sub: npt.NDArray[np.int8],
) -> npt.NDArray[np.int8]:
    """Protocol B's rule: a frame with a plausible head inside it is refused; one whose
    answer lies past the end of the data (a head there without its type or length, or
    the frame's last byte the head's first) waits, for ever."""
    n = len(buf)
    whole = h[plausible]  # plausible heads with their whole header, sorted
    valid = np.flatnonzero(sub == _VALID)
    lo = np.searchsorted(whole, h[valid] + 1, side="left")
    hi = np.searchsorted(whole, stop[valid] - 1, side="right")
    sub[valid[hi > lo]] = _INVALID
    h0, h1 = head
    pending = [
        p
        for p in range(max(n - layout.header + 1, 0), n - 1)
        if buf[p] == h0
        and buf[p + 1] == h1
        and (
            p + layout.type_at >= n
            or (p + layout.length_at >= n and fixed[buf[p + layout.type_at]] >= 0)
        )
    ]
    still = np.flatnonzero(sub == _VALID)
    waits = (stop[still] >= n) & (buf[stop[still] - 1] == h0)
    for p in pending:
        waits |= (h[still] + 1 <= p) & (p <= stop[still] - 1)
    sub[still[waits]] = _NEED
    return sub


def _take_from_the_left(
    heads: _Ints, stops: _Ints, kinds: _Ints, status: npt.NDArray[np.int8]
) -> tuple[_Ints, _Ints, _Ints]:
    """The scanner's walk: frames from the left, skipping heads inside one taken, up to
    the first candidate that waits for more data."""
    live = np.flatnonzero(status != _INVALID)
    s, e, k, st = heads[live], stops[live], kinds[live], status[live]
    if not (st == _NEED).any() and bool(np.all(s[1:] >= e[:-1])):
        return s, e, k  # the usual capture: no overlap, nothing cut off
    keep: list[int] = []
    pos = 0
    for i, (start, stop, state) in enumerate(zip(s.tolist(), e.tolist(), st.tolist(), strict=True)):
        if start < pos:
            continue
        if state == _NEED:
            break
        keep.append(i)
        pos = stop
    return s[keep], e[keep], k[keep]


def _read_columns(
    buf: npt.NDArray[np.uint8],
    starts: _Ints,
    t: npt.NDArray[np.float64],
    layout: FrameLayout,
    columns: tuple[Column, ...],
) -> dict[str, npt.NDArray[Any]]:
    """The fields of same-type frames at ``starts``: one gather, one structured view."""
    offsets = [layout.data_at + c.at for c in columns]
    width = max(o + np.dtype(c.code).itemsize for o, c in zip(offsets, columns, strict=True))
    rows = buf[starts[:, None] + np.arange(width)]
    record = np.dtype(
        {
            "names": [c.name for c in columns],
            "formats": ["<" + c.code for c in columns],
            "offsets": offsets,
            "itemsize": width,
        }
    )
    view = rows.view(record)[:, 0]
    out: dict[str, npt.NDArray[Any]] = {"t": t}
    for c in columns:
        raw = view[c.name]
        out[c.name] = raw.astype(np.int64) if c.divisor is None else raw / c.divisor
    return out
