"""``Notifier``: watching a device from outside, in the spirit of python-can's
``Notifier``: its raw traffic both ways, every message of its named streams, and its
connection states, each delivered synchronously on the event loop as it happens.

It is the way to receive a stream by callback, for applications as for the SDK's own
recorders and bridges, which observe a device through this and through the device's
public methods, never through its private attributes::

    from chassis_sdk import Notifier

    with Notifier(robot) as notifier:
        voltage = notifier.listen("telemetry", lambda t: print(t.voltage))
        notifier.add_tap(my_byte_logger)  # rx(data, now) / tx(frame, now)
        await robot.set_velocity(0.2, 0.0)
        print(voltage.stats)  # calls, time spent, slow calls, error
    # leaving the block (or close()) removes everything it added
"""

from __future__ import annotations

from collections.abc import Callable
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, Self

from .dispatch import SLOW_CALLBACK, Listener, ListenerStats
from .supervisor import ConnectionState

if TYPE_CHECKING:
    from .transport import Tap


class Observable(Protocol):
    """What a `Notifier` needs of a device: its observation hooks (every device has
    them, from `chassis_sdk.core.session.Session`)."""

    @property
    def stream_names(self) -> tuple[str, ...]: ...
    def listen(
        self, stream: str, callback: Callable[[Any], None], *, slow: float = ...
    ) -> Listener[Any]: ...
    def listen_states(
        self, callback: Callable[[ConnectionState], None], *, slow: float = ...
    ) -> Listener[ConnectionState]: ...
    def add_tap(self, tap: Tap) -> None: ...
    def remove_tap(self, tap: Tap) -> None: ...
    def keep_observer(self, observer: object) -> None: ...
    def drop_observer(self, observer: object) -> None: ...


__all__ = ["Notifier"]


class Notifier:
    """Delivers what happens on one device to taps and callbacks until `close`.

    Every callback runs synchronously inside the device's read path (in wire order,
    nothing buffered, no task woken), so it must be quick: never block, never wait
    for I/O, and hand anything slow to the loop (``loop.call_soon``) or to a queue
    that a task drains. In exchange it costs a fraction of what waking an ``async
    for`` does per message.

    A listener's callback that raises is removed at once (it gets nothing more), the
    error logged once with its traceback and kept in its handle's ``error``; the
    other callbacks and subscribers still get that message and the link goes on.
    Each call is timed: one longer than ``slow`` (1 ms by default) logs a warning,
    then at most one summary per 10 s; `listener_stats` says what each costs.
    ``KeyboardInterrupt`` and ``SystemExit`` raised in a callback go on up.

    The device keeps the notifier until `close`, so nothing it added is lost to the
    collector whether or not the caller keeps a reference.

    Args:
        device: The device to watch (connected or not; it goes on across reconnects).

    Example:
        ```python
        import asyncio
        from chassis_sdk import Chassis, Notifier, Telemetry

        async def main() -> None:
            frames: asyncio.Queue[Telemetry] = asyncio.Queue()
            async with Chassis("/dev/ttyUSB0") as robot:
                with Notifier(robot) as notifier:
                    listener = notifier.listen("telemetry", frames.put_nowait)
                    for _ in range(100):
                        print((await frames.get()).voltage)
                    print(listener.stats.calls, listener.stats.max)
        ```
    """

    def __init__(self, device: Observable) -> None:
        self.device = device
        self._taps: list[Tap] = []
        self._listeners: list[Listener[Any]] = []
        device.keep_observer(self)

    @property
    def stream_names(self) -> tuple[str, ...]:
        """The names of the device's streams: the methods that subscribe to them
        (``"telemetry"``, ``"odometry"``, ``"events"``, ...)."""
        return self.device.stream_names

    def add_tap(self, tap: Tap) -> None:
        """Let ``tap`` see every byte of the device's link, both ways: ``tap.rx(data,
        now)`` for each chunk received (or [`feed`][chassis_sdk.Board.feed]),
        ``tap.tx(frame, now)`` for each frame as it begins to leave; ``now`` is
        ``time.monotonic()``."""
        self.device.add_tap(tap)
        self._taps.append(tap)

    def listen(
        self, stream: str, callback: Callable[[Any], None], *, slow: float = SLOW_CALLBACK
    ) -> Listener[Any]:
        """Call ``callback(message)`` for every message of the stream named ``stream``
        (see [`stream_names`][chassis_sdk.core.notifier.Notifier.stream_names]), from now
        on, inside the read path, until `close` (of the handle or of this notifier) or
        until the callback raises.

        Args:
            stream: The stream's name, such as ``"telemetry"``.
            callback: Called with each message; quick, never blocking.
            slow: Seconds past which a call is reported as slow (a warning in the log,
                counted in the handle's ``stats``).

        Returns:
            The listener's handle (a ``Listener``): ``close()`` stops this callback
            alone; ``stats`` (a ``ListenerStats``) gives its calls, the time spent, its
            slow calls and the error that removed it; ``closed`` says whether it
            still listens. This notifier keeps it: it need not be kept.

        Raises:
            ValueError: The device has no stream of that name, or ``slow`` is not a
                finite number > 0.
        """
        listener = self.device.listen(stream, callback, slow=slow)
        self._listeners.append(listener)
        return listener

    def listen_states(
        self, callback: Callable[[ConnectionState], None], *, slow: float = SLOW_CALLBACK
    ) -> Listener[ConnectionState]:
        """Call ``callback(state)`` on every `ConnectionState` change; as `listen`
        (its stream is named ``"connection_states"`` in the log and the stats).

        Raises:
            ValueError: ``slow`` is not a finite number > 0.
        """
        listener = self.device.listen_states(callback, slow=slow)
        self._listeners.append(listener)
        return listener

    @property
    def listeners(self) -> tuple[Listener[Any], ...]:
        """The handles of every callback added by `listen` and `listen_states` until
        `close`, in order, including those removed because they raised."""
        return tuple(self._listeners)

    @property
    def listener_stats(self) -> list[ListenerStats]:
        """What each callback of `listeners` has cost so far: one ``ListenerStats``
        each (stream, callback name, calls, total and longest time in seconds, slow
        calls, bound, and the error that removed it)."""
        return [listener.stats for listener in self._listeners]

    def close(self) -> None:
        """Remove every tap and listener this notifier added (safe to call again)."""
        for tap in self._taps:
            self.device.remove_tap(tap)
        for listener in self._listeners:
            listener.close()
        self._taps.clear()
        self._listeners.clear()
        self.device.drop_observer(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
