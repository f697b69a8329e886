"""``Notifier``: watching a device from outside, in the spirit of python-can's
``Notifier``: its raw traffic both ways, every message of its named streams, and its
connection states, each delivered synchronously on the event loop as it happens.

Recorders, bridges and live views observe a device through this and through the
device's public methods, never through its private attributes::

    from chassis_sdk.core.notifier import Notifier

    with Notifier(robot) as notifier:
        notifier.listen("telemetry", lambda t: print(t.voltage))
        notifier.add_tap(my_byte_logger)  # rx(data, now) / tx(frame, now)
        await robot.set_velocity(0.2, 0.0)
    # leaving the block (or close()) removes everything it added
"""

from __future__ import annotations

from collections.abc import Callable
from types import TracebackType
from typing import TYPE_CHECKING, Any, Self

from .dispatch import Listener
from .supervisor import ConnectionState

if TYPE_CHECKING:
    from .session import Session
    from .transport import Tap

__all__ = ["Notifier"]


class Notifier:
    """Delivers what happens on one device to taps and callbacks until :meth:`close`.

    Every callback runs synchronously inside the device's receive path (in wire
    order, nothing buffered, no task woken): it must be quick and must not raise.
    The device keeps the notifier until :meth:`close`, so nothing it added is lost to
    the collector whether or not the caller keeps a reference.

    Args:
        device: The device to watch (connected or not; it goes on across reconnects).
    """

    def __init__(self, device: Session[Any, Any]) -> None:
        self.device = device
        self._taps: list[Tap] = []
        self._listeners: list[Listener[Any]] = []
        device._notifiers.add(self)

    @property
    def stream_names(self) -> tuple[str, ...]:
        """The names of the device's streams: the methods that subscribe to them
        (``"telemetry"``, ``"odometry"``, ``"events"``, ...)."""
        return tuple(self.device._streams.named)

    def add_tap(self, tap: Tap) -> None:
        """Let ``tap`` see every byte of the device's link, both ways: ``tap.rx(data,
        now)`` for each chunk received (or :meth:`~chassis_sdk.core.session.Session.feed`),
        ``tap.tx(frame, now)`` for each frame as it begins to leave; ``now`` is
        ``time.monotonic()``."""
        self.device._link.add_tap(tap)
        self._taps.append(tap)

    def listen(self, stream: str, callback: Callable[[Any], None]) -> None:
        """Call ``callback(message)`` for every message of the stream named ``stream``
        (see :attr:`stream_names`), from now on.

        Raises:
            ValueError: The device has no stream of that name.
        """
        named = self.device._streams.named
        found = named.get(stream)
        if found is None:
            raise ValueError(
                f"{self.device.device_name} has no stream {stream!r}; it has: {', '.join(named)}"
            )
        self._listeners.append(found.listen(callback))

    def listen_states(self, callback: Callable[[ConnectionState], None]) -> None:
        """Call ``callback(state)`` on every :class:`ConnectionState` change."""
        self._listeners.append(self.device._link.states.listen(callback))

    def close(self) -> None:
        """Remove every tap and listener this notifier added (safe to call again)."""
        for tap in self._taps:
            self.device._link.remove_tap(tap)
        for listener in self._listeners:
            listener.close()
        self._taps.clear()
        self._listeners.clear()
        self.device._notifiers.discard(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
