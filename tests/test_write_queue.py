"""The link's write discipline, sans-IO: what waits while the port cannot take bytes,
what is discarded, what goes next. No port, no loop, no clock: the time is given."""

from __future__ import annotations

import math

from chassis_sdk.core import transport
from chassis_sdk.core.writequeue import QUEUE_LIMIT, WriteQueue

ZERO = b"V0"


def drain(queue: WriteQueue, now: float) -> list[bytes]:
    """What a port that takes everything gets, in order."""
    sent = []
    while (frame := queue.peek(now)) is not None:
        sent.append(frame)
        queue.pop()
    return sent


def test_a_velocity_frame_replaces_the_one_held_and_counts_it() -> None:
    q = WriteQueue()
    assert q.put_velocity(b"V1", 10.0) is True
    assert q.put_velocity(b"V2", 11.0) is True
    assert q.put_velocity(b"V3", 12.0) is True
    assert q.velocity == (b"V3", 12.0)
    assert q.discarded == 2
    assert q.frames == ()
    assert drain(q, 5.0) == [b"V3"]
    assert q.holds is False
    assert q.discarded == 2


def test_an_expired_velocity_frame_is_dropped_not_sent() -> None:
    q = WriteQueue()
    q.put_velocity(b"V1", 10.0)
    assert q.peek(10.5) is None
    assert q.velocity is None
    assert q.holds is False
    assert q.discarded == 1
    assert drain(q, 10.5) == []


def test_a_velocity_frame_is_still_sent_at_its_expiry() -> None:
    q = WriteQueue()
    q.put_velocity(b"V1", 10.0)
    assert drain(q, 10.0) == [b"V1"]
    assert q.discarded == 0


def test_only_the_newest_velocity_counts_for_expiry() -> None:
    q = WriteQueue()
    q.put_velocity(b"V1", 1.0)
    q.put_velocity(b"V2", 3.0)  # replaces V1, which would have expired
    assert drain(q, 2.0) == [b"V2"]
    assert q.discarded == 1


def test_other_frames_keep_their_order_and_go_before_velocity() -> None:
    q = WriteQueue()
    assert q.push(b"R1") is True
    q.put_velocity(b"V1", math.inf)
    assert q.push(b"R2") is True
    q.hold(b"R3")
    assert q.frames == (b"R1", b"R2", b"R3")
    assert q.held_bytes == 6
    assert q.waiting is True
    assert drain(q, 0.0) == [b"R1", b"R2", b"R3", b"V1"]
    assert q.held_bytes == 0
    assert q.waiting is False
    assert q.discarded == 0


def test_peek_does_not_take_and_pop_takes_one() -> None:
    q = WriteQueue()
    q.push(b"R1")
    q.push(b"R2")
    assert q.peek(0.0) == b"R1"
    assert q.peek(0.0) == b"R1"  # the port refused it: it stays first
    q.pop()
    assert q.frames == (b"R2",)
    assert q.held_bytes == 2


def test_the_limit_is_in_bytes_and_a_frame_past_it_is_discarded() -> None:
    q = WriteQueue(limit=10)
    assert q.push(b"aaaa") is True
    assert q.push(b"bbbbbb") is True  # exactly at the limit
    assert q.push(b"c") is False  # one byte past it
    assert q.frames == (b"aaaa", b"bbbbbb")
    assert q.held_bytes == 10
    assert q.discarded == 1
    q.pop()  # room again
    assert q.push(b"dddd") is True
    assert q.push(b"e") is False
    assert q.frames == (b"bbbbbb", b"dddd")
    assert q.discarded == 2


def test_the_default_limit_is_queue_limit_and_the_link_uses_the_same() -> None:
    assert QUEUE_LIMIT == 1024
    assert transport.QUEUE_LIMIT is QUEUE_LIMIT
    q = WriteQueue()
    assert q.limit == QUEUE_LIMIT
    frame = bytes(16)
    accepted = sum(q.push(frame) for _ in range(QUEUE_LIMIT // 16 + 3))
    assert accepted == QUEUE_LIMIT // 16
    assert q.held_bytes == QUEUE_LIMIT
    assert q.discarded == 3


def test_a_frame_the_port_refused_is_held_whatever_the_limit() -> None:
    q = WriteQueue(limit=4)
    q.hold(b"123456")
    assert q.frames == (b"123456",)
    assert q.held_bytes == 6
    assert q.push(b"x") is False
    assert q.discarded == 1


def test_velocity_does_not_count_against_the_limit() -> None:
    q = WriteQueue(limit=4)
    q.put_velocity(b"VVVVVVVV", math.inf)
    assert q.push(b"RRRR") is True
    assert q.held_bytes == 4


def test_closing_velocity_refuses_every_later_velocity_frame() -> None:
    q = WriteQueue()
    q.put_velocity(b"V1", 5.0)
    q.put_velocity(ZERO, math.inf)  # zero wins: V1 is replaced
    q.close_velocity(ZERO)
    assert q.velocity_closed is True
    assert q.zero == ZERO
    assert q.put_velocity(b"V2", 9.0) is False
    assert q.velocity == (ZERO, math.inf)
    assert q.discarded == 1
    assert drain(q, 1e9) == [ZERO]  # the zero never expires


def test_closing_discards_stale_frames_and_the_final_zero_remains() -> None:
    q = WriteQueue()
    q.push(b"R1")
    q.push(b"R2")
    q.put_velocity(b"V1", 5.0)
    q.put_velocity(ZERO, math.inf)
    q.close_velocity(ZERO)
    assert q.discarded == 1  # V1
    assert q.discard_stale(flushed=False) is True
    assert q.frames == ()
    assert q.held_bytes == 0
    assert q.velocity == (ZERO, math.inf)
    assert q.discarded == 3  # V1, R1, R2: the zero is not counted
    assert drain(q, 1e9) == [ZERO]
    assert q.discarded == 3


def test_a_zero_that_had_left_is_held_again_when_the_port_was_flushed() -> None:
    q = WriteQueue()
    q.push(b"R1")
    q.close_velocity(ZERO)  # the zero went straight to the port
    assert q.velocity is None
    assert q.discard_stale(flushed=True) is True
    assert q.velocity == (ZERO, math.inf)
    assert q.frames == ()
    assert q.discarded == 1  # R1


def test_a_zero_that_had_left_an_unflushed_port_is_not_sent_twice() -> None:
    q = WriteQueue()
    q.push(b"R1")
    q.close_velocity(ZERO)
    assert q.discard_stale(flushed=False) is False
    assert q.holds is False
    assert q.discarded == 1


def test_without_a_final_zero_closing_discards_everything() -> None:
    q = WriteQueue()
    q.push(b"R1")
    q.put_velocity(b"V1", 5.0)
    assert q.discard_stale(flushed=True) is False
    assert q.holds is False
    assert q.velocity is None
    assert q.discarded == 2


def test_drop_all_counts_every_frame_held() -> None:
    q = WriteQueue()
    q.push(b"R1")
    q.push(b"R2")
    q.put_velocity(b"V1", 5.0)
    q.put_velocity(b"V2", 5.0)
    assert q.drop_all() == 3
    assert q.discarded == 4  # V1 replaced, then R1, R2, V2
    assert q.frames == ()
    assert q.held_bytes == 0
    assert q.holds is False
    assert q.drop_all() == 0
    assert q.discarded == 4
