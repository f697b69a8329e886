"""The core's collaborators, each tested alone: no port, no device, no simulator.

``Device`` is composed of these; that each works on its own (with a fake writer, a
fake clock or a plain table) is what lets a new device trust them.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import time

import pytest

from chassis_sdk import ChassisError, NotConnectedError, RequestTimeoutError
from chassis_sdk.core.diagnosis import Findings
from chassis_sdk.core.dispatch import Streams
from chassis_sdk.core.events import EdgeDetector, EventKind, RobotEvent
from chassis_sdk.core.requests import Requester
from chassis_sdk.core.supervisor import ConnectionState, ConnectionStates, Writer
from chassis_sdk.core.validation import check_int, check_member, check_probability, check_real

LOG = logging.getLogger("test")


# --- Requester ----------------------------------------------------------------------------


class Wire:
    """A fake link: records frames; ``open`` decides whether a call may write."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.open = True

    def write(self, frame: bytes) -> None:
        self.frames.append(frame)

    def ensure_open(self) -> None:
        if not self.open:
            raise NotConnectedError("closed")


def start_call(
    timeout: float, retries: int = 0
) -> tuple[Wire, Requester[str], asyncio.Future[object]]:
    """A requester on a fake wire, and a read-only call of key "v" started on it."""
    wire = Wire()
    requests: Requester[str] = Requester(
        "fake", wire.write, wire.ensure_open, timeout=timeout, retries=retries, log=LOG
    )
    call = asyncio.ensure_future(requests.call(lambda: (b"?", "v"), read_only=True, name="v"))
    return wire, requests, call


async def written(wire: Wire, frames: int = 1) -> None:
    """Until ``frames`` requests are on the wire."""
    while len(wire.frames) < frames:
        await asyncio.sleep(0.001)


async def test_requester_retries_read_only_calls_then_times_out() -> None:
    wire = Wire()
    requests: Requester[str] = Requester(
        "fake", wire.write, wire.ensure_open, timeout=0.02, retries=2, log=LOG
    )
    with pytest.raises(RequestTimeoutError, match=r"no reply to version from fake .*3 attempts"):
        await requests.call(lambda: (b"?", "v"), read_only=True, name="version")
    assert wire.frames == [b"?"] * 3
    with pytest.raises(RequestTimeoutError, match="1 attempt"):
        await requests.call(lambda: (b"!", "v"), read_only=False, name="set")
    assert len(requests) == 0


async def test_requester_answers_the_call_and_counts_late_and_unmatched_replies() -> None:
    wire, requests, call = start_call(timeout=0.05)
    await written(wire)
    requests.reply("v", 7)
    assert await call == 7
    requests.reply("v", 8)  # nobody asked
    assert (requests.unmatched, requests.late) == (1, 0)
    with pytest.raises(RequestTimeoutError):
        await requests.call(lambda: (b"?", "v"), read_only=True, name="v")
    requests.reply("v", 9)  # the reply to the call that timed out
    assert (requests.unmatched, requests.late) == (1, 1)


async def test_a_reply_wakes_its_call_on_the_next_loop_turn() -> None:
    # The reply wakes the waiting task itself: with asyncio.wait in between (a done
    # callback that wakes the waiter that wakes the task) it took one turn more.
    wire, requests, call = start_call(timeout=5.0)
    await written(wire)
    requests.reply("v", 7)
    await asyncio.sleep(0)
    assert call.done()
    assert call.result() == 7


async def test_a_reply_to_an_earlier_attempt_answers_the_retry() -> None:
    wire, requests, call = start_call(timeout=0.05, retries=2)
    await written(wire, 2)  # the first attempt timed out; the second is waiting
    requests.reply("v", 7)  # the reply to the first request
    assert await call == 7
    assert (requests.unmatched, requests.late) == (0, 0)
    requests.reply("v", 7)  # the second request's own reply comes after: late
    assert (requests.unmatched, requests.late) == (0, 1)


async def test_a_cancelled_call_gives_up_its_key_and_its_reply_is_late() -> None:
    wire, requests, call = start_call(timeout=5.0)
    await written(wire)
    call.cancel()
    with pytest.raises(asyncio.CancelledError):
        await call
    assert len(requests) == 0
    requests.reply("v", 7)
    assert (requests.unmatched, requests.late) == (0, 1)


async def test_requester_writes_nothing_when_the_link_is_down() -> None:
    wire = Wire()
    wire.open = False
    requests: Requester[str] = Requester(
        "fake", wire.write, wire.ensure_open, timeout=1.0, retries=2, log=LOG
    )
    with pytest.raises(NotConnectedError):
        await requests.call(lambda: (b"?", "v"), read_only=True, name="v")
    assert wire.frames == []


async def test_requester_fail_all_ends_every_call() -> None:
    wire, requests, call = start_call(timeout=5.0)
    await written(wire)
    requests.fail_all(None)
    with pytest.raises(NotConnectedError, match="fake was closed"):
        await call


# --- ConnectionStates and Writer ----------------------------------------------------------


class Owner:
    """What the supervisor's pieces call back."""

    def __init__(self) -> None:
        self.changes: list[tuple[ConnectionState, ConnectionState]] = []
        self.fences = 0

    def state_changed(self, old: ConnectionState, new: ConnectionState) -> None:
        self.changes.append((old, new))

    def fenced(self) -> None:
        self.fences += 1

    def closing_frame(self) -> bytes | None:
        return b"0"


async def test_connection_states_report_each_change_once_and_wake_waiters() -> None:
    owner = Owner()
    states = ConnectionStates("fake", owner.state_changed, 8, LOG)
    states.renew()
    sub = states.subscribe()
    waiter = asyncio.ensure_future(states.wait_open(1.0))
    states.set(ConnectionState.CONNECTING)
    states.set(ConnectionState.CONNECTING)  # no change, nothing reported
    states.set(ConnectionState.STALE)
    await waiter
    states.set(ConnectionState.DISCONNECTED)
    states.end_subscriptions()
    assert [s async for s in sub] == [
        ConnectionState.CONNECTING,
        ConnectionState.STALE,
        ConnectionState.DISCONNECTED,
    ]
    assert len(owner.changes) == 3
    with pytest.raises(NotConnectedError, match="fake is disconnected"):
        await states.wait_open(1.0)


def test_the_writer_refuses_every_write_without_a_link_and_after_the_fence() -> None:
    owner = Owner()
    states = ConnectionStates("fake", owner.state_changed, 8, LOG)
    writer: Writer[object] = Writer(owner, states)
    with pytest.raises(NotConnectedError, match="fake is disconnected"):
        writer.write(b"x")
    with pytest.raises(NotConnectedError):
        writer.write_velocity(b"v", 1.0)
    writer.fence()
    assert owner.fences == 1
    with pytest.raises(NotConnectedError, match="fake is closing"):
        writer.ensure_open()
    assert (writer.bytes_sent, writer.frames_sent) == (0, 0)


# --- Streams --------------------------------------------------------------------------------


async def test_streams_keep_the_latest_value_and_end_together() -> None:
    streams = Streams(2)
    a, b = streams.new(), streams.new()
    sub = a.subscribe()
    for n in range(5):
        a.publish(n)
    assert (a.latest, b.latest) == (4, None)
    assert streams.dropped == 3  # a queue of 2 kept the newest
    streams.fail(ChassisError("gone"))
    assert [await anext(sub), await anext(sub)] == [3, 4]
    with pytest.raises(ChassisError, match="gone"):
        await anext(sub)
    streams.reopen()
    assert a.latest == 4  # kept across a reconnect


# --- EdgeDetector and Findings --------------------------------------------------------------


class Mode(enum.Enum):
    IDLE = 0
    BUSY = 1


class Flags(enum.IntFlag):
    STOP = 1
    BUMP = 2
    NOTE = 4


def test_edges_come_from_the_device_table_once_per_change() -> None:
    table = [
        (Flags.STOP, EventKind.ESTOP_ENGAGED, EventKind.ESTOP_RELEASED, "panel"),
        (Flags.BUMP, EventKind.BUMPER_HIT, EventKind.BUMPER_CLEARED, "front"),
    ]
    edges = EdgeDetector(table, EventKind.DOCKING_CHANGED)
    assert edges.update(Flags.STOP, Mode.IDLE, 1.0) == [
        RobotEvent(EventKind.ESTOP_ENGAGED, "panel", 1.0)
    ]
    assert edges.update(Flags.STOP | Flags.NOTE, Mode.IDLE, 2.0) == []  # unwatched bit
    assert edges.update(Flags.BUMP, Mode.BUSY, 3.0) == [
        RobotEvent(EventKind.ESTOP_RELEASED, "panel", 3.0),
        RobotEvent(EventKind.BUMPER_HIT, "front", 3.0),
        RobotEvent(EventKind.DOCKING_CHANGED, "", 3.0, state=Mode.BUSY),
    ]
    assert str(edges.update(Flags.BUMP, Mode.IDLE, 4.0)[0]) == "docking changed: IDLE"


def test_a_word_that_differs_only_in_an_unwatched_bit_stays_the_usual_case() -> None:
    # A chassis under host control reports REMOTE_OFFLINE, a bit no edge watches, in
    # every frame: the levels kept are the whole word, so after the first such frame
    # the next ones are the usual case (nothing to build), and a caller on the read
    # path can skip the call by comparing with ``bits`` and ``state``.
    table = [(Flags.STOP, EventKind.ESTOP_ENGAGED, EventKind.ESTOP_RELEASED, "panel")]
    edges = EdgeDetector(table)
    assert edges.update(Flags.NOTE, Mode.IDLE, 1.0) == []
    assert (edges.bits, edges.state) == (Flags.NOTE, Mode.IDLE)
    assert edges.update(Flags.NOTE, Mode.IDLE, 2.0) == ()  # the shared "no events"
    assert edges.update(Flags.NOTE | Flags.STOP, Mode.IDLE, 3.0) == [
        RobotEvent(EventKind.ESTOP_ENGAGED, "panel", 3.0)
    ]
    assert edges.update(Flags.STOP, Mode.IDLE, 4.0) == []  # NOTE went: no edge
    assert edges.update(Flags.STOP, Mode.IDLE, 5.0) == ()


def test_findings_name_every_set_bit_faults_apart_from_notes() -> None:
    found = Findings()
    found.flags("status", Flags.STOP | Flags.NOTE | Flags(16), Flags.STOP | Flags.BUMP)
    found.fault("link stale")
    assert found.faults == ["status STOP", "link stale"]
    assert found.notes == ["status NOTE", "status BIT_4"]


# --- validation -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("check", "value", "error", "match"),
    [
        pytest.param(lambda v: check_real(v, "x"), True, TypeError, "x must be a number", id="real-bool"),
        pytest.param(lambda v: check_real(v, "x"), "1", TypeError, "x must be a number", id="real-str"),
        pytest.param(lambda v: check_real(v, "x"), float("nan"), ValueError, "finite", id="real-nan"),
        pytest.param(lambda v: check_real(v, "x"), 10**400, ValueError, "finite", id="real-huge-int"),
        pytest.param(lambda v: check_real(v, "x", low=0, low_open=True), 0, ValueError, "> 0", id="real-open"),
        pytest.param(lambda v: check_int(v, "n", low=1), 1.0, TypeError, "n must be an integer", id="int-float"),
        pytest.param(lambda v: check_int(v, "n", low=1), False, TypeError, "n must be an integer", id="int-bool"),
        pytest.param(lambda v: check_int(v, "n", low=0, high=9), 10, ValueError, "0 to 9", id="int-range"),
        pytest.param(lambda v: check_probability(v, "p"), 1.5, ValueError, "0 to 1", id="probability"),
        pytest.param(lambda v: check_member(Mode, v, "mode", "use 0 or 1"), True, TypeError, "unknown mode", id="member-bool"),
        pytest.param(lambda v: check_member(Mode, v, "mode", "use 0 or 1"), 2, ValueError, "use 0 or 1", id="member-unknown"),
    ],
)  # fmt: skip
def test_every_bad_number_gets_one_kind_of_message(
    check: object, value: object, error: type[Exception], match: str
) -> None:
    # As the standard library does: a wrong type is a TypeError, a bad value a ValueError.
    with pytest.raises(error, match=match) as info:
        check(value)  # type: ignore[operator]
    assert type(info.value) is error


# --- enums that print as what they mean ---------------------------------------------------


def test_named_flags_and_enums_print_names_and_stay_numbers() -> None:
    from chassis_sdk import ChassisStatus, DockingState, DriverError

    s = ChassisStatus.REMOTE_OFFLINE | ChassisStatus.FRONT_BUMPER
    assert (str(s), f"{s}", f"{s:>28}") == (
        "REMOTE_OFFLINE|FRONT_BUMPER",
        "REMOTE_OFFLINE|FRONT_BUMPER",
        " REMOTE_OFFLINE|FRONT_BUMPER",
    )
    assert (f"{s:d}", f"{s:#06x}", int(s), s & ChassisStatus.BUMPER) == (
        "1032",
        "0x0408",
        1032,
        ChassisStatus.FRONT_BUMPER,
    )
    assert str(DriverError(0)) == "none"
    assert str(ChassisStatus(1 << 14)) == "BIT_14"  # undocumented bits are named too
    assert (str(DockingState.DOCKED), f"{DockingState.DOCKED:d}") == ("DOCKED", "4")
    assert repr(DockingState.DOCKED) == "<DockingState.DOCKED: 4>"


def test_a_listener_sees_every_item_at_once_and_outlives_a_failed_stream() -> None:
    from chassis_sdk.core.dispatch import Broadcast

    stream: Broadcast[int] = Broadcast(2)
    seen: list[int] = []
    listener = stream.listen(seen.append)
    for i in range(5):  # more than any subscriber's buffer: a listener keeps nothing
        stream.publish(i)
    assert seen == [0, 1, 2, 3, 4]  # synchronously, in order, none dropped
    stream.fail(None)  # the link was lost: iterations end, a listener stays
    stream.reopen()
    stream.publish(5)
    assert seen[-1] == 5
    listener.close()
    stream.publish(6)
    assert seen[-1] == 5
    assert stream.dropped == 0


def test_a_velocity_command_is_checked_and_made_once() -> None:
    from chassis_sdk.core.motion import frame_builder

    made: list[tuple[float, float]] = []

    def make(a: float, b: float) -> tuple[float, float]:
        if a != a:  # NaN
            raise ValueError("linear must be a number")
        made.append((a, b))
        return (a, b)

    build = frame_builder(make, lambda m: repr(m).encode(), 0.3, 0.1)
    assert made == [(0.3, 0.1)]  # checked (and made) when the command is given
    assert build(0.3, 0.1) == b"(0.3, 0.1)"
    assert build(0.3, 0.1) == b"(0.3, 0.1)"
    assert made == [(0.3, 0.1)]  # every resend reuses it
    assert build(0.2, 0.1) == b"(0.2, 0.1)"  # a ramped or clamped value is made anew
    assert made == [(0.3, 0.1), (0.2, 0.1)]
    with pytest.raises(ValueError, match="linear"):
        frame_builder(make, lambda m: b"", float("nan"), 0.0)


# --- what leaves the process: wall time, the monotonic reading named --------------------


@pytest.mark.timing
def test_outbound_json_carries_wall_time_and_names_the_monotonic_reading() -> None:
    from chassis_sdk.core.events import EventKind, RobotEvent
    from chassis_sdk.core.plain import outbound

    now = time.monotonic()
    body = outbound(RobotEvent(EventKind.BUMPER_HIT, source="front", timestamp=now - 2.0))
    assert body["monotonic"] == now - 2.0
    assert abs(body["timestamp"] - (time.time() - 2.0)) < 0.5
    assert "monotonic" not in outbound({"value": 1})
