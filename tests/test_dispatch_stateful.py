"""Hypothesis stateful tests of the shared dispatch machinery: the request table and
the fan-out, each checked step by step against a plain model of what it must do."""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

import hypothesis.strategies as st
from hypothesis import settings
from hypothesis.stateful import (
    Bundle,
    RuleBasedStateMachine,
    consumes,
    invariant,
    precondition,
    rule,
)

from chassis_sdk._dispatch import Broadcast, RequestTable, Subscription

T = TypeVar("T")
KEYS = st.sampled_from([0x87, 0x88, 0x89, ("led", 1), ("led", 2)])


class _Loop:
    """Runs synchronous calls inside a running event loop (futures need one)."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()

    def call(self, fn: Callable[[], T]) -> T:
        async def inside() -> T:
            return fn()

        return self.loop.run_until_complete(inside())

    def call_async(self, coro: Any) -> Any:
        return self.loop.run_until_complete(coro)

    def close(self) -> None:
        self.loop.close()


class RequestTableMachine(RuleBasedStateMachine):
    """The table against a model: per key, a FIFO of futures (including ones cancelled
    but not yet discarded, which a resolve must skip)."""

    waiters = Bundle("waiters")

    def __init__(self) -> None:
        super().__init__()
        self.rt = _Loop()
        self.table: RequestTable[Any, int] = RequestTable()
        self.model: dict[Any, list[asyncio.Future[int]]] = {}

    @rule(target=waiters, key=KEYS)
    def expect(self, key: Any) -> tuple[Any, asyncio.Future[int]]:
        fut = self.rt.call(lambda: self.table.expect(key))
        self.model.setdefault(key, []).append(fut)
        return key, fut

    @rule(key=KEYS, value=st.integers())
    def resolve(self, key: Any, value: int) -> None:
        queue = self.model.get(key, [])
        live = next((f for f in queue if not f.done()), None)
        assert self.table.resolve(key, value) is (live is not None)
        if live is None:
            self.model.pop(key, None)
            return
        assert live.result() == value
        del queue[: queue.index(live) + 1]  # skipped dead waiters go with it
        if not queue:
            del self.model[key]

    @rule(w=consumes(waiters))
    def give_up(self, w: tuple[Any, asyncio.Future[int]]) -> None:
        """A timeout or cancellation, as ``Device._request`` handles it."""
        key, fut = w
        fut.cancel()
        self.table.discard(key, fut)
        queue = self.model.get(key, [])
        if fut in queue:
            queue.remove(fut)
            if not queue:
                del self.model[key]

    @rule(w=consumes(waiters))
    def cancel_without_discard(self, w: tuple[Any, asyncio.Future[int]]) -> None:
        w[1].cancel()

    @rule()
    def fail_all(self) -> None:
        error = ConnectionError("lost")
        self.table.fail_all(error)
        for queue in self.model.values():
            for fut in queue:
                if not fut.cancelled():
                    assert fut.exception() is error
        self.model.clear()

    @invariant()
    def agrees_with_model(self) -> None:
        assert len(self.table) == sum(len(q) for q in self.model.values())
        for key in (0x87, 0x88, 0x89, ("led", 1), ("led", 2)):
            assert self.table.pending(key) is bool(self.model.get(key))

    def teardown(self) -> None:
        self.rt.close()


class _SubModel:
    def __init__(self, maxlen: int) -> None:
        self.buffer: deque[int] = deque(maxlen=maxlen)
        self.dropped = 0
        self.ended = False
        self.error: BaseException | None = None


class BroadcastMachine(RuleBasedStateMachine):
    """The fan-out against a model: each subscriber a bounded deque, drop-oldest."""

    subs = Bundle("subs")
    MAXLEN = 4

    def __init__(self) -> None:
        super().__init__()
        self.rt = _Loop()
        self.bc: Broadcast[int] = Broadcast(self.MAXLEN)
        self.model: dict[Subscription[int], _SubModel] = {}
        self.closed = False
        self.error: BaseException | None = None
        self.total_dropped = 0

    @rule(target=subs)
    def subscribe(self) -> Subscription[int]:
        sub = self.bc.subscribe()
        m = _SubModel(self.MAXLEN)
        if self.closed:
            m.ended, m.error = True, self.error
        self.model[sub] = m
        return sub

    @rule(item=st.integers())
    def publish(self, item: int) -> None:
        self.bc.publish(item)
        for m in self.model.values():
            if m.ended:
                continue
            if len(m.buffer) == self.MAXLEN:
                m.dropped += 1
                self.total_dropped += 1
            m.buffer.append(item)

    @rule(sub=subs)
    def read(self, sub: Subscription[int]) -> None:
        m = self.model[sub]
        if m.buffer:
            assert self.rt.call_async(anext(sub)) == m.buffer.popleft()
        elif m.ended:
            expected = type(m.error) if m.error is not None else StopAsyncIteration
            try:
                self.rt.call_async(anext(sub))
            except expected:
                pass
            else:
                raise AssertionError("an ended subscription yielded")

    @rule(sub=consumes(subs))
    def close(self, sub: Subscription[int]) -> None:
        sub.close()
        m = self.model.pop(sub)
        assert m is not None
        try:
            self.rt.call_async(anext(sub))
        except StopAsyncIteration:
            pass
        else:
            raise AssertionError("a closed subscription yielded")

    @rule(with_error=st.booleans())
    def fail(self, with_error: bool) -> None:
        error = ConnectionError("lost") if with_error else None
        self.bc.fail(error)
        self.closed, self.error = True, error
        for m in self.model.values():
            if not m.ended:
                m.ended, m.error = True, error

    @precondition(lambda self: self.closed)
    @rule()
    def reopen(self) -> None:
        self.bc.reopen()
        self.closed, self.error = False, None

    @invariant()
    def agrees_with_model(self) -> None:
        for sub, m in self.model.items():
            assert list(sub._buffer) == list(m.buffer)
            assert len(sub._buffer) <= self.MAXLEN
            assert sub.dropped == m.dropped
        assert self.bc.dropped == self.total_dropped
        assert len(self.bc) == sum(1 for m in self.model.values() if not m.ended)

    def teardown(self) -> None:
        self.rt.close()


TestRequestTable = RequestTableMachine.TestCase
TestRequestTable.settings = settings(max_examples=150, stateful_step_count=40, deadline=None)
TestBroadcast = BroadcastMachine.TestCase
TestBroadcast.settings = settings(max_examples=150, stateful_step_count=40, deadline=None)
