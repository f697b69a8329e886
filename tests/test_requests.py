"""Replies and calls: a late reply never answers a later call, a device slower than
the timeout never returns stale data, every reply answers its own call however slow the
device, and a very late reply does not answer a request that reused its id.

From the field hardening of issue 11, against the stand-ins of ``standin.py`` and the
numbered replies of ``stalls.py``, on ptys and TCP.
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from chassis_sdk import Board, Chassis, RequestTimeoutError

from .support.helpers import TRANSPORTS, until
from .support.stalls import NumberedReplies, own_answers
from .support.standin import BoardStandIn, Received, frame_b

pytestmark = pytest.mark.integration

# --- a late reply never answers a later call -----------------------------------------------------


async def test_a_late_reply_does_not_answer_the_next_call() -> None:
    async with (
        NumberedReplies(noise=False, delays=[0.35, 0.3]) as dev,
        Chassis(dev.port, request_timeout=0.2, retries=0) as robot,
    ):
        with pytest.raises(RequestTimeoutError):
            await robot.get_firmware_version()
        robot.request_timeout = 1.0
        # The first reply arrives while this call waits: it is not this call's.
        assert await robot.get_firmware_version() == 2
        assert robot.stats.late_replies == 1
        assert robot.stats.unmatched_replies == 0


async def test_a_device_slower_than_the_timeout_never_returns_stale_data() -> None:
    async with (
        NumberedReplies(noise=False, delays=[0.3] * 10) as dev,
        Chassis(dev.port, request_timeout=0.2, retries=0) as robot,
    ):
        for _ in range(3):
            with pytest.raises(RequestTimeoutError):
                await robot.get_firmware_version()
        await until(lambda: robot.stats.late_replies == 3)
        assert robot.stats.unmatched_replies == 0


@pytest.mark.parametrize("tcp", TRANSPORTS)
@pytest.mark.parametrize("factor", [1.1, 1.5, 3.0])
async def test_on_a_slow_device_every_reply_answers_its_own_call(tcp: bool, factor: float) -> None:
    # Every reply comes `factor` request timeouts after its request, numbered by the
    # request it answers: a call may only ever return one of its own attempts' numbers.
    # Before the latency-following quarantine, at 1.5x a call got the reply to the
    # previous call's second attempt (the quarantine, one request_timeout, ran out first).
    timeout = 0.15
    async with (
        NumberedReplies(noise=False, tcp=tcp, latency=factor * timeout) as dev,
        Chassis(dev.port, request_timeout=timeout, retries=2) as robot,
    ):
        answers = await own_answers(dev, robot, 4)
        assert all(a is None or a in own for own, a in answers), answers
        if factor < 2.5:  # (at 3x a reply comes just as its call's last attempt times out)
            assert sum(a is not None for _, a in answers) >= 2, answers  # it does answer
        assert robot.stats.unmatched_replies == 0


async def test_a_reply_to_an_earlier_attempt_answers_the_same_call() -> None:
    async with (
        NumberedReplies(noise=False, delays=[0.3, 0.25]) as dev,
        Chassis(dev.port, request_timeout=0.2, retries=2) as robot,
    ):
        # Attempt 1 at 0 s (answered at 0.3 s), attempt 2 at 0.2 s (answered at 0.45):
        # the first reply to come answers the call; the other is late.
        assert await robot.get_firmware_version() == 1
        assert await robot.get_firmware_version() == 3  # after the late one went by
        assert robot.stats.late_replies == 1


@dataclass
class _VeryLateBoard(BoardStandIn):
    """Holds the reply to the first LED request (claiming the LED is on) and sends it
    just before answering the 257th: after 256 allocations the old round-robin gave
    that request the same id."""

    _stale: bytes = b""

    def on_frame(self, rec: Received) -> None:
        if rec.kind == 0x01:
            n = len(self.of_kind(0x01))
            if n == 1:
                self._stale = frame_b(b"\xfe\xce", 0x01, bytes((rec.payload[1], 1)))
                return
            if n == 257:
                self.send(self._stale)
        super().on_frame(rec)


async def test_a_very_late_board_reply_does_not_answer_a_request_with_a_reused_id() -> None:
    async with (
        _VeryLateBoard(noise=False) as dev,
        Board(dev.port, request_timeout=0.1, retries=0) as board,
    ):
        with pytest.raises(RequestTimeoutError):
            await board.get_led()
        board.request_timeout = 1.0
        for _ in range(256):
            assert await board.get_led() is False
        assert board.stats.late_replies == 1
        ids = [f.payload[1] for f in dev.of_kind(0x01)]
        assert ids[0] not in ids[1:]  # retired for the quarantine
