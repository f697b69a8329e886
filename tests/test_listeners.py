"""Callback delivery (issue 29, item 2): a callback runs in the read path, so one that
raises is logged once, counted and removed without ending the link, and one that is slow
is measured, warned about once and then summarised at most every 10 s."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time

import pytest

import chassis_sdk
from chassis_sdk import Chassis, ConnectionState, Listener, ListenerStats, Notifier, Telemetry
from chassis_sdk.core.dispatch import SLOW_CALLBACK, SLOW_SUMMARY_INTERVAL, Broadcast
from chassis_sdk.sim import ChassisSimulator

MS = 0.001  # s


class FakeClock:
    """Seconds that pass only when a test says so."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _records(caplog: pytest.LogCaptureFixture, level: int) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name == "chassis_sdk" and r.levelno == level]


# --- a callback that raises ------------------------------------------------------------------


def test_a_raising_callback_is_removed_logged_once_and_counted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    stream: Broadcast[int] = Broadcast(4, name="telemetry")
    before: list[int] = []
    after: list[int] = []
    failed: list[int] = []

    def broken(item: int) -> None:
        failed.append(item)
        raise OSError("disk full")

    first = stream.listen(before.append)
    bad = stream.listen(broken)
    last = stream.listen(after.append)
    sub = stream.subscribe()
    for i in range(3):
        stream.publish(i)
    assert failed == [0]  # removed after its first error: nothing more
    assert before == after == [0, 1, 2]  # the rest got that message and the later ones
    assert list(sub._buffer) == [0, 1, 2]
    assert bad.closed
    assert not first.closed
    assert not last.closed
    assert isinstance(bad.error, OSError)
    assert stream.listener_errors == 1
    assert len(stream) == 3  # two listeners and the subscription
    errors = _records(caplog, logging.ERROR)
    assert len(errors) == 1  # once, not once per message
    message = errors[0].getMessage()
    assert "broken" in message
    assert "'telemetry'" in message
    assert "removed" in message
    assert errors[0].exc_info is not None
    assert errors[0].exc_info[1] is bad.error
    stats = bad.stats
    assert (stats.calls, stats.error, stats.stream) == (1, bad.error, "telemetry")
    assert stats.callback.endswith("broken")
    bad.close()  # closing it again is harmless
    assert stream.listener_errors == 1


def test_keyboard_interrupt_and_system_exit_go_on_up_and_blame_no_callback() -> None:
    stream: Broadcast[int] = Broadcast(4)
    for error in (KeyboardInterrupt, SystemExit):

        def interrupted(item: int, error: type[BaseException] = error) -> None:
            raise error

        listener = stream.listen(interrupted)
        with pytest.raises(error):
            stream.publish(1)
        assert not listener.closed
        assert listener.error is None
        listener.close()
    assert stream.listener_errors == 0


def test_a_cancelled_error_from_a_callback_is_its_failure_not_the_links() -> None:
    stream: Broadcast[int] = Broadcast(4)
    seen: list[int] = []

    def looks_at_a_cancelled_future(item: int) -> None:
        raise asyncio.CancelledError

    listener = stream.listen(looks_at_a_cancelled_future)
    other = stream.listen(seen.append)
    stream.publish(1)  # does not raise out of the read path
    stream.publish(2)
    assert listener.closed
    assert isinstance(listener.error, asyncio.CancelledError)
    assert seen == [1, 2]
    other.close()


# --- a slow callback -------------------------------------------------------------------------


def test_a_slow_callback_is_measured_warned_once_then_summarised_every_10_s(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = FakeClock()
    stream: Broadcast[float] = Broadcast(4, name="odometry", clock=clock)

    def writer(item: float) -> None:
        clock.now += item  # it takes as long as it is told

    listener = stream.listen(writer)
    stream.publish(0.2 * MS)  # under the bound
    assert _records(caplog, logging.WARNING) == []
    stream.publish(5 * MS)
    warnings = _records(caplog, logging.WARNING)
    assert len(warnings) == 1
    message = warnings[0].getMessage()
    assert "writer" in message
    assert "'odometry'" in message
    assert "5.00 ms" in message
    assert "bound of 1 ms" in message
    stats = listener.stats
    assert stats.calls == 2
    assert stats.slow == 1
    assert stats.max == pytest.approx(0.005)
    assert stats.total == pytest.approx(0.0052)
    assert stats.mean == pytest.approx(0.0026)
    assert stats.bound == SLOW_CALLBACK
    # Slow on every message from now on: no more lines for 10 s of (fake) time...
    for _ in range(3):
        stream.publish(3 * MS)
        clock.now += 4_000 * MS  # the rest of the time between messages
    assert len(_records(caplog, logging.WARNING)) == 1
    stream.publish(7 * MS)  # ... then one summary of all that came since
    warnings = _records(caplog, logging.WARNING)
    assert len(warnings) == 2
    summary = warnings[1].getMessage()
    assert "4 more calls over 1 ms" in summary
    assert "7.00 ms" in summary
    for _ in range(20):  # and the next one not before another 10 s
        stream.publish(2 * MS)
    assert len(_records(caplog, logging.WARNING)) == 2
    clock.now += SLOW_SUMMARY_INTERVAL
    stream.publish(2 * MS)
    assert len(_records(caplog, logging.WARNING)) == 3
    assert "21 more calls" in _records(caplog, logging.WARNING)[2].getMessage()
    assert listener.stats.slow == 26  # every slow call counted, logged or not
    assert listener.stats.calls == 27


def test_each_listener_is_timed_alone_and_its_bound_is_its_own(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = FakeClock()
    stream: Broadcast[int] = Broadcast(4, clock=clock)

    def quick(item: int) -> None:
        clock.now += 0.001 * MS

    def slow(item: int) -> None:
        clock.now += 3 * MS

    fast = stream.listen(quick)
    tolerant = stream.listen(slow, slow=0.005)
    strict = stream.listen(slow, slow=0.002)
    stream.publish(0)
    assert [fast.stats.max, tolerant.stats.max, strict.stats.max] == pytest.approx(
        [1e-6, 0.003, 0.003]
    )
    assert [fast.stats.slow, tolerant.stats.slow, strict.stats.slow] == [0, 0, 1]
    assert len(_records(caplog, logging.WARNING)) == 1
    with pytest.raises(ValueError, match="slow"):
        stream.listen(quick, slow=0)
    assert len(stream) == 3  # the refused one was never added


def test_calls_count_what_each_was_called_with_from_joining_to_leaving() -> None:
    stream: Broadcast[int] = Broadcast(4)
    stream.publish(0)  # before anyone listens
    seen: dict[str, list[int]] = {"a": [], "b": [], "late": []}
    later: list[Listener[int]] = []

    def a(item: int) -> None:
        seen["a"].append(item)
        if item == 2:
            b.close()  # during a publish: b still gets this one
            later.append(stream.listen(seen["late"].append))  # and this one from the next

    first = stream.listen(a)
    b = stream.listen(seen["b"].append)
    for i in range(1, 5):
        stream.publish(i)
    assert seen == {"a": [1, 2, 3, 4], "b": [1, 2], "late": [3, 4]}
    assert [first.stats.calls, b.stats.calls, later[0].stats.calls] == [4, 2, 2]
    stream.publish(5)
    assert b.stats.calls == 2  # frozen when it left


def test_listened_says_whether_anyone_takes_the_stream_dropped_members_included() -> None:
    # The read path reads ``listened`` on every frame to decide whether a pose is worth
    # building: it must follow every way a member comes and goes, a member simply
    # dropped (held weakly) included.
    stream: Broadcast[int] = Broadcast(4)
    assert stream.listened is False
    listener = stream.listen(lambda item: None)
    assert stream.listened is True
    del listener  # collected at once (reference counting): it unlistens itself
    assert stream.listened is False
    sub = stream.subscribe()
    assert stream.listened is True
    del sub
    assert stream.listened is False
    raising = stream.listen(lambda item: 1 / 0)
    stream.publish(1)  # the callback raised: removed
    assert raising.closed
    assert stream.listened is False
    sub = stream.subscribe()
    stream.fail(None)  # subscriptions end; nothing listens any more
    assert stream.listened is False
    assert sub is not None


def test_a_partial_is_named_by_what_it_wraps() -> None:
    stream: Broadcast[int] = Broadcast(4)
    latest: dict[str, int] = {}
    listener = stream.listen(functools.partial(latest.__setitem__, "telemetry"))
    stream.publish(1)
    assert latest == {"telemetry": 1}
    assert listener.stats.callback == "partial(dict.__setitem__)"


# --- through a Notifier, on a real link ------------------------------------------------------


@pytest.mark.integration
async def test_on_a_real_link_a_raising_callback_goes_and_the_device_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    failed: list[Telemetry] = []
    seen: list[Telemetry] = []
    enough = asyncio.Event()

    def broken(message: Telemetry) -> None:
        failed.append(message)
        raise RuntimeError("bridge lost its broker")

    def good(message: Telemetry) -> None:
        seen.append(message)
        if len(seen) >= 5:
            enough.set()

    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        with Notifier(robot) as notifier:
            bad = notifier.listen("telemetry", broken)
            ok = notifier.listen("telemetry", good)
            async with asyncio.timeout(10):
                await enough.wait()
            assert len(failed) == 1
            assert seen[0] is failed[0]
            assert bad.closed
            assert isinstance(bad.error, RuntimeError)
            assert not ok.closed
            assert robot.connection_state is ConnectionState.CONNECTED
            assert isinstance(await robot.get_firmware_version(), int)
            async for frame in robot.telemetry():  # and the streams go on
                assert frame.seq != failed[0].seq
                break
            assert [s.error is not None for s in notifier.listener_stats] == [True, False]
    assert len(failed) == 1
    assert len(_records(caplog, logging.ERROR)) == 1


@pytest.mark.integration
async def test_on_a_real_link_a_slow_callback_is_warned_about_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    seen = 0
    enough = asyncio.Event()

    def busy(message: Telemetry) -> None:
        nonlocal seen
        end = time.perf_counter() + 0.005
        while time.perf_counter() < end:
            pass
        seen += 1
        if seen >= 5:
            enough.set()

    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        with Notifier(robot) as notifier:
            listener = notifier.listen("telemetry", busy)
            async with asyncio.timeout(10):
                await enough.wait()
            stats = listener.stats
    assert isinstance(stats, ListenerStats)
    assert stats.calls >= 5
    assert stats.slow == stats.calls
    assert stats.max >= 0.005
    assert stats.total >= 0.005 * stats.calls
    warnings = [r for r in _records(caplog, logging.WARNING) if "busy" in r.getMessage()]
    assert len(warnings) == 1  # the first; a summary comes at most every 10 s


def test_a_notifier_hands_back_each_listener_and_their_stats() -> None:
    robot = Chassis("/dev/never-opened")
    seen: list[object] = []
    states: list[ConnectionState] = []
    with Notifier(robot) as notifier:
        listener = notifier.listen("telemetry", seen.append, slow=0.01)
        watching = notifier.listen_states(states.append, slow=0.02)
        assert isinstance(listener, Listener)
        assert listener.callback == seen.append
        assert notifier.listeners == (listener, watching)
        telemetry, connection = notifier.listener_stats
        assert (telemetry.stream, telemetry.bound, telemetry.calls) == ("telemetry", 0.01, 0)
        assert (connection.stream, connection.bound) == ("connection_states", 0.02)
        with pytest.raises(ValueError, match="slow"):
            notifier.listen_states(states.append, slow=float("nan"))
        assert len(notifier.listeners) == 2
        listener.close()  # that callback alone
        assert listener.closed
        assert not watching.closed
    assert watching.closed


def test_the_listener_api_is_public() -> None:
    for name in ("Notifier", "Listener", "ListenerStats"):
        assert name in chassis_sdk.__all__
        assert name in chassis_sdk.core.__all__
    assert chassis_sdk.Notifier is Notifier


# --- leaving an async for by an exception ------------------------------------------------------


async def test_a_loop_left_by_cancellation_or_timeout_unsubscribes_at_once() -> None:
    # "An exception unsubscribes at once" (Subscription): the traceback of a cancelled
    # or timed-out wait keeps the waiting frame, which must not keep what the loop
    # iterated, or the dead subscription would buffer, count drops and keep the
    # stream "listened" (odometry built for no one) until the traceback goes.
    stream: Broadcast[int] = Broadcast(4)

    async def consume() -> None:
        async for _ in stream.subscribe():
            pass

    task = asyncio.create_task(consume())
    await asyncio.sleep(0)  # it waits for the first item
    assert stream.listened is True
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task  # the task, and its exception's traceback, are still held here
    assert len(stream) == 0
    assert stream.listened is False

    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(0.01):
            async for _ in stream.subscribe():
                pass
    assert len(stream) == 0  # before any further await
    assert stream.listened is False
    for item in range(10):
        stream.publish(item)
    assert stream.dropped == 0
