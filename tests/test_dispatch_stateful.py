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

from chassis_sdk.core.dispatch import (
    LATENCY_MARGIN,
    MAX_LATENCY,
    Broadcast,
    Listener,
    Reply,
    RequestTable,
    Subscription,
)

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


class _FakeTimeLoop(asyncio.SelectorEventLoop):
    """An event loop whose clock only moves when the test says: timers (the table's
    quarantine wake-ups) fire exactly when the model says they are due."""

    now = 1000.0

    def time(self) -> float:
        return self.now


QUARANTINE = 2.0


class _Call:
    def __init__(self, key: Any, task: asyncio.Task[asyncio.Future[int]]) -> None:
        self.key = key
        self.task = task
        self.answered = False


class RequestTableMachine(RuleBasedStateMachine):
    """The table against a model of its rule: one call per key (the others wait in
    order), replies counted in flight per key, a reply with no live call is late if one
    was in flight, and a key with overdue replies is quarantined: for ``QUARANTINE``
    after its release, and until its last write is ``LATENCY_MARGIN`` times the worst
    latency seen old (each reply measured from the oldest write still waiting)."""

    calls = Bundle("calls")

    def __init__(self) -> None:
        super().__init__()
        self.loop = _FakeTimeLoop()
        self.table: RequestTable[Any, int] = RequestTable(QUARANTINE, clock=self.loop.time)
        # The model, per key: the call holding it, replies in flight, quarantine end,
        # calls waiting in order.
        self.holder: dict[Any, _Call | None] = {}
        self.sent_at: dict[Any, deque[float]] = {}
        self.latency = 0.0
        self.until: dict[Any, float] = {}
        self.waiting: dict[Any, deque[_Call]] = {}

    def settle(self) -> None:
        for _ in range(5):
            self.loop.run_until_complete(asyncio.sleep(0))

    def hand_over(self, key: Any) -> None:
        """The model's rule for who holds ``key`` next."""
        queue = self.waiting.setdefault(key, deque())
        if self.holder.get(key) is not None or not queue:
            return
        if self.in_flight(key) and self.loop.now < self.until.get(key, 0.0):
            return
        self.holder[key] = queue.popleft()
        self.sent_at[key] = deque()

    def in_flight(self, key: Any) -> int:
        return len(self.sent_at.get(key, ()))

    def overdue(self, key: Any) -> float:
        return self.sent_at[key][-1] + LATENCY_MARGIN * self.latency

    @rule(target=calls, key=KEYS)
    def start(self, key: Any) -> _Call:
        task = self.loop.create_task(self.table.acquire(key))
        call = _Call(key, task)
        self.waiting.setdefault(key, deque()).append(call)
        self.hand_over(key)
        self.settle()
        return call

    @rule(call=calls)
    def send(self, call: _Call) -> None:
        if self.holder.get(call.key) is call:
            self.table.sent(call.key)
            self.sent_at[call.key].append(self.loop.now)

    @rule(key=KEYS, value=st.integers())
    def reply(self, key: Any, value: int) -> None:
        holder = self.holder.get(key)
        live = holder is not None and not holder.task.result().done()
        had = self.in_flight(key)
        if had and holder is None and self.loop.now >= self.until.get(key, 0.0):
            self.sent_at[key].clear()  # taken as lost already: not measured
        elif had:
            latency = self.loop.now - self.sent_at[key].popleft()
            self.latency = max(self.latency, min(latency, MAX_LATENCY))
            if holder is None and self.in_flight(key):
                self.until[key] = max(self.until.get(key, 0.0), self.overdue(key))
        expected = Reply.MATCHED if live else Reply.LATE if had else Reply.UNMATCHED
        assert self.table.resolve(key, value) is expected
        if live:
            assert holder is not None
            assert holder.task.result().result() == value
            holder.answered = True
        self.hand_over(key)
        self.settle()

    @rule(call=consumes(calls))
    def finish(self, call: _Call) -> None:
        """The call ends: answered, timed out, or cancelled while holding the key."""
        if self.holder.get(call.key) is call:
            self.table.release(call.key)
            self.holder[call.key] = None
            if self.in_flight(call.key):
                self.until[call.key] = max(self.loop.now + QUARANTINE, self.overdue(call.key))
        elif call in self.waiting.get(call.key, ()):
            call.task.cancel()
            self.waiting[call.key].remove(call)
        else:
            return
        self.hand_over(call.key)
        self.settle()

    @rule(dt=st.sampled_from([0.5, 1.0, 2.5]))
    def time_passes(self, dt: float) -> None:
        self.loop.now += dt
        for key in list(self.waiting):
            self.hand_over(key)
        self.settle()

    @rule()
    def fail_all(self) -> None:
        error = ConnectionError("lost")
        self.table.fail_all(error)
        self.settle()
        for call in self.holder.values():
            if call is not None:  # an unanswered call fails; an answered one keeps it
                outcome = call.task.result().exception()
                assert (outcome is None) if call.answered else isinstance(outcome, ConnectionError)
        for queue in self.waiting.values():
            for call in queue:
                assert isinstance(call.task.exception(), ConnectionError)
        self.holder.clear()
        self.sent_at.clear()
        self.until.clear()
        self.waiting.clear()

    @invariant()
    def agrees_with_model(self) -> None:
        for key in (0x87, 0x88, 0x89, ("led", 1), ("led", 2)):
            holder = self.holder.get(key)
            if holder is not None:
                assert holder.task.done(), "the model gave it the key"
            for call in self.waiting.get(key, ()):
                assert not call.task.done(), "the model has it waiting"
            assert self.table.in_flight(key) == self.in_flight(key) or (
                holder is None and not self.waiting.get(key)
            )
        assert len(self.table) == sum(1 for h in self.holder.values() if h is not None)

    def teardown(self) -> None:
        for queue in self.waiting.values():
            for call in queue:
                call.task.cancel()
        self.settle()
        self.loop.close()


class _SubModel:
    def __init__(self, maxlen: int) -> None:
        self.buffer: deque[int] = deque(maxlen=maxlen)
        self.dropped = 0
        self.ended = False
        self.error: BaseException | None = None


class BroadcastMachine(RuleBasedStateMachine):
    """The fan-out against a model: each subscriber a bounded deque, drop-oldest."""

    subs = Bundle("subs")
    listeners = Bundle("listeners")
    MAXLEN = 4

    def __init__(self) -> None:
        super().__init__()
        self.rt = _Loop()
        self.bc: Broadcast[int] = Broadcast(self.MAXLEN)
        self.model: dict[Subscription[int], _SubModel] = {}
        self.closed = False
        self.error: BaseException | None = None
        self.total_dropped = 0
        self.heard: list[int] = []
        self.listening = 0  # listeners not closed nor dropped

    @rule(target=listeners)
    def listen(self) -> Listener[int]:
        self.listening += 1
        return self.bc.listen(self.heard.append)

    @rule(listener=consumes(listeners))
    def unlisten(self, listener: Listener[int]) -> None:
        # (A dropped one is let go too, but hypothesis keeps every value it made:
        # tests/test_listeners.py drops them.)
        listener.close()
        self.listening -= 1

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
        live = sum(1 for m in self.model.values() if not m.ended)
        assert len(self.bc) == live + self.listening
        # What the read path checks on every frame before it builds a message.
        assert self.bc.listened is (live + self.listening > 0)

    def teardown(self) -> None:
        self.rt.close()


TestRequestTable = RequestTableMachine.TestCase
TestRequestTable.settings = settings(max_examples=150, stateful_step_count=40, deadline=None)
TestBroadcast = BroadcastMachine.TestCase
TestBroadcast.settings = settings(max_examples=150, stateful_step_count=40, deadline=None)
