"""``chassis_sdk.sync``: the devices with blocking methods, for scripts and notebooks.

::

    from chassis_sdk import sync

    with sync.Chassis("/dev/ttyUSB0") as robot:
        print(robot.get_chassis_info())
        robot.set_velocity(0.2, 0.0, duration=1.0)
        for t in robot.telemetry():          # a plain iterator
            print(t.linear)
            if t.linear > 0.15:
                break                         # unsubscribes

Why it is shaped so
-------------------
The SDK is asyncio; a script, a notebook cell or a program that is not async should not
have to learn ``async``/``await`` to move a robot, and must not lose the safety net
that the event loop provides. So each blocking device owns a **background thread**
running its own event loop (an anyio `BlockingPortal`,
started by `open`), and the async device lives there, with its watchdog and its
deadman. The calling thread only waits on it. Whatever the caller does next (sleep,
block on input, compute for a minute, raise), the loop goes on: a velocity command
without ``duration`` expires ``command_timeout`` after the last call and zero is
written, as with the async API.

* Every blocking method has the async method's signature and docstring, plus a
  keyword ``timeout`` (seconds; default `default_timeout`: the
  device's ``request_timeout`` for each attempt, plus a second). A call that does not
  finish in time raises [`RequestTimeoutError`][chassis_sdk.RequestTimeoutError] (a
  ``TimeoutError``), and is cancelled in the loop. Methods that take a ``timeout`` of
  their own (``verify``, ``wait_for``, ``emergency_stop(confirm=True)``...) keep its
  meaning; the wait is bounded by it plus `default_timeout`.
* Streams (``telemetry()``, ``imu()``, ``events()``...) are plain iterators
  (`BlockingIterator`) with a per-item ``timeout``; leaving the ``for`` loop
  (``break``, an exception) or `BlockingIterator.close` unsubscribes in the loop.
* **Ctrl-C** (``KeyboardInterrupt``) during a blocking call cancels the call, writes
  zero velocity (`stop`) and re-raises ``KeyboardInterrupt``.
* **Exit**: leaving ``with``, `close`, the object being garbage-collected, and
  the interpreter's exit (``atexit``) each close the device: zero is written and
  flushed, then the thread ends.
* **SIGTERM and SIGHUP** kill Python on the spot by default, with no ``atexit``. When a
  blocking device is opened from the main thread and a signal's handler is the
  default, it is replaced (``stop_on_signals=True``) by one that raises
  ``SystemExit(128 + signal)`` in the main thread, so the ``with`` block unwinds (or
  ``atexit`` runs) and zero is written, as [`chassis_sdk.run`][chassis_sdk.run] does for async
  programs; a second signal takes the default action. The default handler is put back
  when the last blocking device closes. A handler the application installed is never
  replaced.
* **SIGKILL** (``kill -9``, the OOM killer) cannot be caught: nothing is written, and
  only the firmware's own command timeout (0.5 s without a velocity frame) stops the
  wheels.

Calling from a thread that runs an event loop (a Jupyter cell, a callback) works: the
device's loop is another one, in another thread. A blocking call made from a coroutine
blocks that coroutine's loop until it returns; that is the caller's choice (in async
code, use the async API).

The async device is [`device`][chassis_sdk.sync.BlockingDevice.device] and its loop's portal
`portal`, to run more coroutines beside it (an integration, a
recorder): ``robot.portal.call(some_coroutine_function, robot.device)``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import inspect
import math
import os
import signal
import threading
import weakref
from collections.abc import Awaitable, Callable
from types import FrameType, TracebackType
from typing import TYPE_CHECKING, Any, ClassVar, Generic, ParamSpec, Self, TypeVar

import anyio
from anyio.from_thread import BlockingPortal, start_blocking_portal

from .core.device import Device
from .core.dispatch import Subscription
from .core.transport import wait_lingering
from .core.validation import check_optional
from .devices import profile
from .devices.board.device import Board as AsyncBoard
from .devices.chassis.device import Chassis as AsyncChassis
from .devices.config import Profile, constructor_options
from .errors import ChassisError, NotConnectedError, RequestTimeoutError
from .sim import simulator

if TYPE_CHECKING:
    import datetime

    from .core.diagnosis import Diagnosis
    from .core.events import RobotEvent
    from .core.motion import MotionLimits, MoveResult
    from .core.odometry import Odometry
    from .core.stats import LinkStats
    from .core.supervisor import ConnectionState
    from .devices.board.messages import BatteryReading, ImuSample, VelocityFeedback
    from .devices.chassis.health import ChassisDiagnosis
    from .devices.chassis.messages import ChassisInfo, DriverStatus, PowerTelemetry, Telemetry
    from .sim.server import SimulatorServer

__all__ = [
    "MARGIN",
    "BlockingDevice",
    "BlockingIterator",
    "Board",
    "Chassis",
    "Simulator",
    "blocking_class",
    "open",
]

P = ParamSpec("P")
R = TypeVar("R")
T = TypeVar("T")
D = TypeVar("D", bound=Device[Any, Any])

#: Seconds a blocking call waits beyond its own bound (the loop's answer in flight).
MARGIN = 1.0
#: Streams whose items come when something happens, not at a rate: no per-item bound
#: unless one is given.
_EDGE_STREAMS = frozenset({"events", "logs", "connection_states"})
#: Names of the async device that the blocking one implements its own way.
_OWN = frozenset({"connect", "close"})
_NOTE = (
    "\n\n(Blocking twin of the async method: waits at most ``timeout`` seconds; "
    "Ctrl-C stops the robot and raises KeyboardInterrupt. See :mod:`chassis_sdk.sync`.)"
)


def _bound(timeout: float | None, default: float, name: str = "timeout") -> float:
    """``timeout`` checked (finite, > 0), or ``default`` for ``None``."""
    checked = check_optional(timeout, name, low=0, low_open=True, unit="s")
    return default if checked is None else checked


# --- the loop thread --------------------------------------------------------------------------


class _Loop:
    """A background thread running an event loop and an anyio portal into it."""

    def __init__(self, name: str) -> None:
        self._cm = start_blocking_portal(name=name)
        self.portal: BlockingPortal = self._cm.__enter__()
        self.aio: asyncio.AbstractEventLoop = self.portal.call(asyncio.get_running_loop)
        self.thread: threading.Thread = self.portal.call(threading.current_thread)
        self.stopped = False

    def run(
        self,
        bound: float,
        call: Callable[[], Awaitable[R]],
        what: str,
        interrupted: Callable[[], None] | None = None,
    ) -> R:
        """Run ``call()`` in the loop and wait for it, at most ``bound`` seconds there
        (``math.inf``: no bound) and [`MARGIN`][chassis_sdk.sync.MARGIN] more here."""

        async def bounded() -> R:
            try:
                with anyio.fail_after(None if math.isinf(bound) else bound):
                    return await call()
            except TimeoutError as exc:
                if isinstance(exc, ChassisError):
                    raise
                raise RequestTimeoutError(f"{what} did not finish within {bound:g} s") from None

        if threading.current_thread() is self.thread:
            raise RuntimeError(f"{what}: a blocking call from the device's own loop thread")
        future: concurrent.futures.Future[R] | None = None
        try:
            future = self.portal.start_task_soon(bounded, name=what)
            done, _ = concurrent.futures.wait(
                [future], None if math.isinf(bound) else bound + MARGIN
            )
        except RuntimeError:  # the portal has stopped
            raise NotConnectedError(f"{what}: the device is closed") from None
        except BaseException:  # KeyboardInterrupt, or SystemExit from a signal
            if future is not None:
                future.cancel()
            if interrupted is not None:
                interrupted()
            raise
        if not done:
            future.cancel()
            raise RequestTimeoutError(
                f"{what}: the SDK's event loop did not answer within {bound + MARGIN:g} s"
            )
        try:
            return future.result()
        except concurrent.futures.CancelledError:
            raise NotConnectedError(f"{what} was cancelled: the device was closed") from None

    def run_sync(
        self,
        bound: float,
        fn: Callable[[], R],
        what: str,
        interrupted: Callable[[], None] | None = None,
    ) -> R:
        """Call ``fn()`` in the loop thread (the device's state lives there); Ctrl-C
        while waiting calls ``interrupted`` as `run` does."""

        async def call() -> R:
            return fn()

        return self.run(bound, call, what, interrupted)

    def soon(self, fn: Callable[[], object]) -> None:
        """Call ``fn()`` in the loop thread without waiting (any thread, GC included)."""
        with contextlib.suppress(RuntimeError):  # the loop is closed: nothing to undo
            self.aio.call_soon_threadsafe(fn)

    def stop(self) -> None:
        """End the loop (cancelling what still runs there) and join its thread."""
        if threading.current_thread() is self.thread:
            raise RuntimeError("a loop cannot stop itself from its own thread")
        self.stopped = True
        with contextlib.suppress(RuntimeError):  # already stopped
            self.portal.call(self.portal.stop, True)
        self._cm.__exit__(None, None, None)


# --- SIGTERM / SIGHUP -------------------------------------------------------------------------

_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))
_signal_lock = threading.RLock()  # re-entrant: a finalizer may release inside a hold
_signal_users = 0
_installed: list[signal.Signals] = []


def _on_signal(signum: int, frame: FrameType | None) -> None:
    # A second signal, while this one unwinds, takes the default action (ends Python).
    for sig in _installed:
        signal.signal(sig, signal.SIG_DFL)
    raise SystemExit(128 + signum)


def _hold_signals() -> bool:
    """Install the stopping handlers (main thread, default handlers only)."""
    global _signal_users
    if threading.current_thread() is not threading.main_thread():
        return False
    with _signal_lock:
        if _signal_users == 0:
            _installed.clear()
            for sig in _STOP_SIGNALS:
                if signal.getsignal(sig) is signal.SIG_DFL:
                    signal.signal(sig, _on_signal)
                    _installed.append(sig)
        _signal_users += 1
    return True


def _release_signals() -> None:
    global _signal_users
    with _signal_lock:
        _signal_users -= 1
        if _signal_users > 0:
            return
        for sig in _installed:
            if signal.getsignal(sig) is _on_signal:
                try:
                    signal.signal(sig, signal.SIG_DFL)
                except ValueError:  # not the main thread (GC elsewhere): leave it be
                    return
        _installed.clear()


# --- closing, on every path ------------------------------------------------------------------


class _Open:
    """What closing an open device needs, without the blocking object (for its finalizer)."""

    __slots__ = ("__weakref__", "bound", "device", "loop", "signals")

    def __init__(self, loop: _Loop, device: Device[Any, Any], bound: float, signals: bool) -> None:
        self.loop = loop
        self.device = device
        self.bound = bound
        self.signals = signals


def _shutdown(state: _Open) -> None:
    """Close the device in its loop (zero written and flushed, a lingering zero given its
    time), then end the loop. From the loop's own thread (the last reference dropped
    there), a helper thread does it."""
    if threading.current_thread() is state.loop.thread:
        threading.Thread(target=_shutdown, args=(state,), name="chassis_sdk.sync close").start()
        return
    device = state.device

    async def closing() -> None:
        await device.close()
        await wait_lingering()

    what = f"close {device.port}"
    try:
        try:
            state.loop.run(state.bound, closing, what)
        except (KeyboardInterrupt, SystemExit):
            # Interrupted while closing (a second Ctrl-C, a signal): the close is
            # shielded in the loop; wait for it once more, then go on raising.
            with contextlib.suppress(Exception):
                state.loop.run(state.bound, closing, what)
            raise
    finally:
        state.loop.stop()
        if state.signals:
            _release_signals()


# --- iterators ----------------------------------------------------------------------------------


class BlockingIterator(Generic[T]):
    """A device stream as a plain iterator: ``for t in robot.telemetry(): ...``.

    Each item waits at most the ``timeout`` given when it was made (then
    `RequestTimeoutError`). Leaving the loop (``break``, an exception,
    the iterator dropped), `close` or a ``with`` block unsubscribes, in the
    device's loop. Ctrl-C while waiting for an item stops the robot, as any blocking
    call does. It ends when the device closes and raises what the async iterator
    raises (``ConnectionLostError`` when the link drops without ``reconnect``).
    """

    def __init__(
        self,
        loop: _Loop,
        subscription: Subscription[T],
        bound: float,
        what: str,
        interrupted: Callable[[], None],
    ) -> None:
        self._loop = loop
        self._subscription: Subscription[T] | None = subscription
        self._bound = bound
        self._what = what
        self._interrupted = interrupted

    def __iter__(self) -> Self:
        return self

    def __next__(self) -> T:
        sub = self._subscription
        if sub is None or self._loop.stopped:  # closed, or its device was
            self.close()
            raise StopIteration

        async def item() -> tuple[T] | None:
            try:
                return (await sub.__anext__(),)
            except StopAsyncIteration:
                return None

        try:
            got = self._loop.run(self._bound, item, f"next {self._what}", self._interrupted)
        except BaseException:
            self.close()
            raise
        if got is None:
            self.close()
            raise StopIteration
        return got[0]

    @property
    def dropped(self) -> int:
        """Items this iterator lost by falling ``queue_size`` behind."""
        sub = self._subscription
        return 0 if sub is None else sub.dropped

    def close(self) -> None:
        """Unsubscribe (in the device's loop, without waiting); idempotent."""
        sub, self._subscription = self._subscription, None
        if sub is not None:
            self._loop.soon(sub.close)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


# --- the devices ----------------------------------------------------------------------------------


class BlockingDevice(Generic[D]):
    """A device in a background loop, with blocking methods (see `chassis_sdk.sync`):
    the base of `Chassis`, [`Board`][chassis_sdk.sync.Board] and the classes `blocking_class`
    makes for other devices.

    Subclasses name their async device class (``class Chassis(BlockingDevice[...],
    device=AsyncChassis)``); every public member of it that a subclass does not define
    is made here, from the async class (methods, streams, properties), so nothing is
    left out; the ones a subclass defines are typed, and take the async docstrings.
    """

    _async_class: ClassVar[type[Device[Any, Any]]]

    def __init_subclass__(cls, *, device: type[Device[Any, Any]], **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._async_class = device
        cls.device_name = device.device_name
        for name, member in _public_members(device):
            if name in _OWN:
                continue
            defined = next((k.__dict__[name] for k in cls.__mro__ if name in k.__dict__), None)
            if defined is None:
                setattr(cls, name, _twin(name, member))
            elif isinstance(defined, property) and not defined.__doc__:
                setattr(cls, name, property(defined.fget, defined.fset, doc=member.__doc__))
            elif inspect.isfunction(defined) and not defined.__doc__:
                defined.__doc__ = (member.__doc__ or "") + _NOTE

    device_name: ClassVar[str]

    def __init__(self, port: str, *, stop_on_signals: bool = True, **options: Any) -> None:
        """Make the device; no I/O and no thread until `open`.

        Args:
            port: As for the async device: a device path, a pty path or
                ``socket://host:port``.
            stop_on_signals: While open, SIGTERM and SIGHUP raise ``SystemExit`` in the
                main thread (when their handlers are the default), so the robot is
                stopped on the way out (see [`chassis_sdk.sync`][chassis_sdk.sync]).
            **options: The async device's keyword options (``request_timeout``,
                ``command_timeout``, ``reconnect``, ``limits``...), checked now.

        Raises:
            TypeError, ValueError: As the async constructor (nothing is opened).
        """
        if not isinstance(stop_on_signals, bool):
            raise TypeError(f"stop_on_signals must be True or False, got {stop_on_signals!r}")
        self._device: D = self._async_class(port, **options)  # type: ignore[assignment]
        self._stop_on_signals = stop_on_signals
        self._connect_bound = float(options.get("connect_timeout", 2.0)) + MARGIN
        self._close_bound = float(options.get("close_linger", 5.0)) + 2 * MARGIN
        self._state: _Open | None = None
        self._finalizer: weakref.finalize[Any, Any] | None = None

    @classmethod
    def from_config(
        cls,
        config: str | os.PathLike[str] | Profile | None = None,
        *,
        stop_on_signals: bool = True,
        **overrides: Any,
    ) -> Self:
        """This device as the robot profile describes it (the file ``config`` names,
        else the one found; see `chassis_sdk.devices.config`), not yet open:
        ``with sync.Chassis.from_config() as robot:``. ``overrides`` beat the file.

        Raises:
            ProfileError: The profile is wrong, its ``[robot] device`` is another
                device, or it names no port and none is given.
        """
        options = constructor_options(config, cls.device_name, overrides)
        return cls(stop_on_signals=stop_on_signals, **options)

    # --- lifetime -------------------------------------------------------------------------

    def open(self, *, timeout: float | None = None) -> Self:
        """Start the background loop and open the port in it (the async ``connect``).
        Returns the device, so ``robot = sync.Chassis(port).open()`` works in a notebook.

        Raises:
            PortOpenError: The port cannot be opened.
            ChassisError: Already open.
            RequestTimeoutError: Opening took longer than ``timeout`` (default:
                ``connect_timeout`` plus a second).
        """
        bound = _bound(timeout, self._connect_bound)
        if self._state is not None:
            raise ChassisError(f"{self.port} is already open")
        loop = _Loop(f"chassis_sdk.sync {self.port}")
        device = self._device
        try:
            loop.run(bound, device.connect, f"open {self.port}")
        except BaseException:
            try:
                loop.run(self._close_bound, device.close, f"close {self.port}")
            finally:
                loop.stop()
            raise
        signals = self._stop_on_signals and _hold_signals()
        self._state = _Open(loop, device, self._close_bound, signals)
        # atexit (weakref.finalize runs then) and garbage collection both close it.
        self._finalizer = weakref.finalize(self, _shutdown, self._state)
        return self

    def connect(self, *, timeout: float | None = None) -> None:
        """The async ``connect``: `open` without returning the device."""
        self.open(timeout=timeout)

    def close(self, *, timeout: float | None = None) -> None:
        """Stop the robot (zero written and flushed), close the port and end the loop
        thread. Safe to call more than once.

        Args:
            timeout: Bound on the close (default: ``close_linger`` plus two seconds).
        """
        bound = _bound(timeout, self._close_bound)
        state, self._state = self._state, None
        if state is None:
            return
        state.bound = bound
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None
        _shutdown(state)

    def __enter__(self) -> Self:
        # ``with sync.open(...) as robot:`` enters a device that is open already.
        return self if self._state is not None else self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<sync.{type(self).__name__} {self.port!r} {'open' if self._state else 'closed'}>"

    # --- what the wrappers use ------------------------------------------------------------

    @property
    def device(self) -> D:
        """The async device. It lives in the background loop: use it only there (through
        [`portal`][chassis_sdk.sync.BlockingDevice.portal])."""
        return self._device

    @property
    def portal(self) -> BlockingPortal:
        """The anyio portal into the device's loop, to run coroutines beside it.

        Raises:
            NotConnectedError: Not open.
        """
        return self._loop().portal

    @property
    def port(self) -> str:
        """The port, as given."""
        return self._device.port

    @property
    def default_timeout(self) -> float:
        """The bound of a call without ``timeout``: ``request_timeout`` for each attempt
        of a read-only request, plus [`MARGIN`][chassis_sdk.sync.MARGIN]."""
        d = self._device
        return d.request_timeout * (d.retries + 1) + MARGIN

    def _loop(self) -> _Loop:
        state = self._state
        if state is None:
            raise NotConnectedError(f"{self.port} is not open; use `with` or open() first")
        return state.loop

    def _interrupted(self) -> None:
        """Ctrl-C (or a stopping signal) while waiting: write zero now."""
        state = self._state
        if state is None:
            return
        with contextlib.suppress(Exception):  # closed, read-only: nothing to stop
            state.loop.run(MARGIN, self._device.stop, f"stop {self.port}")

    def _call(
        self,
        timeout: float | None,
        fn: Callable[P, Awaitable[R]],
        /,
        *args: P.args,
        **kwargs: P.kwargs,
    ) -> R:
        """Run ``fn(*args, **kwargs)`` (a method of the async device) in the loop, bounded
        by ``timeout`` (default `default_timeout`)."""
        bound = _bound(timeout, self.default_timeout)
        loop = self._loop()
        what = getattr(fn, "__name__", "call")
        return loop.run(bound, functools.partial(fn, *args, **kwargs), what, self._interrupted)

    def _own_timeout(self, timeout: float | None) -> float | None:
        """A method's own ``timeout`` checked (the wait is bounded by it plus the default)."""
        return check_optional(timeout, "timeout", low=0, low_open=True, unit="s")

    def _call_own(
        self,
        timeout: float | None,
        fn: Callable[P, Awaitable[R]],
        /,
        *args: P.args,
        **kwargs: P.kwargs,
    ) -> R:
        """As `_call` for a method with a ``timeout`` of its own (``None``: none)."""
        own = self._own_timeout(timeout)
        bound = math.inf if own is None else own + self.default_timeout
        loop = self._loop()
        what = getattr(fn, "__name__", "call")
        return loop.run(bound, functools.partial(fn, *args, **kwargs), what, self._interrupted)

    def _read(self, fn: Callable[[D], R], timeout: float | None = None) -> R:
        """``fn(device)`` in the loop thread (directly while closed: no loop runs)."""
        state = self._state
        if state is None:
            return fn(self._device)
        bound = _bound(timeout, self.default_timeout)
        # Ctrl-C in a property read stops the robot as in any other blocking call
        # (a loop of `robot.latest_odometry` spends nearly all its time here).
        return state.loop.run_sync(
            bound, lambda: fn(self._device), f"read {self.port}", self._interrupted
        )

    def _iterate(
        self, timeout: float | None, subscribe: Callable[[], Subscription[T]], what: str
    ) -> BlockingIterator[T]:
        default = math.inf if what in _EDGE_STREAMS else self.default_timeout
        bound = _bound(timeout, default)
        loop = self._loop()
        sub = loop.run_sync(self.default_timeout, subscribe, f"subscribe {what}", self._interrupted)
        return BlockingIterator(
            loop, sub, bound, f"{what} item from {self.port}", self._interrupted
        )

    if TYPE_CHECKING:
        # Members generated from the async class without a typed twin below are Any.
        def __getattr__(self, name: str) -> Any: ...

    # --- typed twins of what every device has ---------------------------------------------

    def set_velocity(
        self,
        linear: float,
        angular: float,
        *,
        duration: float | None = None,
        timeout: float | None = None,
    ) -> None:
        return self._call(timeout, self._device.set_velocity, linear, angular, duration=duration)

    def stop(self, *, timeout: float | None = None) -> None:
        return self._call(timeout, self._device.stop)

    def verify(self, timeout: float = 3.0) -> None:
        return self._call_own(timeout, self._device.verify, timeout)

    def drive_distance(
        self,
        distance: float,
        speed: float | None = None,
        *,
        tolerance: float | None = None,
        timeout: float | None = None,
        kind: str = "goal",
    ) -> MoveResult:
        return self._call_own(
            timeout,
            self._device.drive_distance,
            distance,
            speed,
            tolerance=tolerance,
            timeout=timeout,
            kind=kind,
        )

    def rotate(
        self,
        angle: float,
        rate: float | None = None,
        *,
        tolerance: float | None = None,
        timeout: float | None = None,
        kind: str = "goal",
    ) -> MoveResult:
        return self._call_own(
            timeout,
            self._device.rotate,
            angle,
            rate,
            tolerance=tolerance,
            timeout=timeout,
            kind=kind,
        )

    def go_to(
        self,
        x: float,
        y: float,
        heading: float | None = None,
        *,
        speed: float | None = None,
        tolerance: float | None = None,
        timeout: float | None = None,
        kind: str = "goal",
    ) -> MoveResult:
        return self._call_own(
            timeout,
            self._device.go_to,
            x,
            y,
            heading,
            speed=speed,
            tolerance=tolerance,
            timeout=timeout,
            kind=kind,
        )

    def wait_connected(self, timeout: float | None = None) -> None:
        return self._call_own(timeout, self._device.wait_connected, timeout)

    def events(self, *, timeout: float | None = None) -> BlockingIterator[RobotEvent]:
        return self._iterate(timeout, self._device.events, "events")

    def odometry(self, *, timeout: float | None = None) -> BlockingIterator[Odometry]:
        return self._iterate(timeout, self._device.odometry, "odometry")

    def connection_states(
        self, *, timeout: float | None = None
    ) -> BlockingIterator[ConnectionState]:
        return self._iterate(timeout, self._device.connection_states, "connection_states")

    def reset_odometry(
        self,
        x: float = 0.0,
        y: float = 0.0,
        heading: float = 0.0,
        *,
        timeout: float | None = None,
    ) -> None:
        return self._read(lambda d: d.reset_odometry(x, y, heading), timeout)

    @property
    def is_connected(self) -> bool:
        return self._read(lambda d: d.is_connected)

    @property
    def connection_state(self) -> ConnectionState:
        return self._read(lambda d: d.connection_state)

    @property
    def stats(self) -> LinkStats:
        return self._read(lambda d: d.stats)

    @property
    def latest_odometry(self) -> Odometry | None:
        return self._read(lambda d: d.latest_odometry)

    @property
    def commanded_velocity(self) -> tuple[float, float] | None:
        return self._read(lambda d: d.commanded_velocity)

    @property
    def written_velocity(self) -> tuple[float, float]:
        return self._read(lambda d: d.written_velocity)

    @property
    def command_timeout(self) -> float | None:
        return self._read(lambda d: d.command_timeout)

    @property
    def battery_percentage(self) -> float | None:
        return self._read(lambda d: d.battery_percentage)

    @property
    def limits(self) -> MotionLimits:
        return self._read(lambda d: d.limits)

    @limits.setter
    def limits(self, limits: MotionLimits | None) -> None:
        def assign(d: D) -> None:
            d.limits = limits

        self._read(assign)


def _public_members(cls: type) -> list[tuple[str, Any]]:
    """The public members of an async device class that a blocking twin mirrors."""
    found = []
    for name in dir(cls):
        if name.startswith("_"):
            continue
        raw = inspect.getattr_static(cls, name)
        if isinstance(raw, property) or inspect.isfunction(raw):
            found.append((name, raw))
    return found


def _returns_subscription(fn: Callable[..., Any]) -> bool:
    annotation = inspect.signature(fn).return_annotation
    return "Subscription" in str(getattr(annotation, "__name__", annotation))


def _twin(name: str, member: Any) -> Any:
    """A blocking member made from the async class's ``member`` called ``name``."""
    if isinstance(member, property):
        fset = member.fset

        def get(self: BlockingDevice[Any]) -> Any:
            return self._read(lambda d: getattr(d, name))

        def set_(self: BlockingDevice[Any], value: Any) -> None:
            self._read(lambda d: setattr(d, name, value))

        return property(get, set_ if fset is not None else None, doc=member.__doc__)
    sig = inspect.signature(member)
    own = "timeout" in sig.parameters
    params = list(sig.parameters.values())
    if not own:
        params.append(inspect.Parameter("timeout", inspect.Parameter.KEYWORD_ONLY, default=None))
    blocking_sig = sig.replace(parameters=params)

    if inspect.iscoroutinefunction(member):

        def method(self: BlockingDevice[Any], *args: Any, **kwargs: Any) -> Any:
            bound = blocking_sig.bind(self, *args, **kwargs)  # TypeError here, not there
            bound.apply_defaults()
            timeout = bound.arguments["timeout"] if own else kwargs.pop("timeout", None)
            fn = getattr(self._device, name)
            if own:
                return self._call_own(timeout, fn, *args, **kwargs)
            return self._call(timeout, fn, *args, **kwargs)

    elif _returns_subscription(member):

        def method(self: BlockingDevice[Any], *args: Any, **kwargs: Any) -> Any:
            blocking_sig.bind(self, *args, **kwargs)
            timeout = kwargs.pop("timeout", None)
            fn = getattr(self._device, name)
            return self._iterate(timeout, lambda: fn(*args, **kwargs), name)

    else:

        def method(self: BlockingDevice[Any], *args: Any, **kwargs: Any) -> Any:
            blocking_sig.bind(self, *args, **kwargs)
            timeout = None if own else kwargs.pop("timeout", None)
            return self._read(lambda d: getattr(d, name)(*args, **kwargs), timeout)

    method.__name__ = method.__qualname__ = name
    method.__doc__ = (member.__doc__ or "") + _NOTE
    method.__signature__ = blocking_sig  # type: ignore[attr-defined]
    return method


class Chassis(BlockingDevice[AsyncChassis], device=AsyncChassis):
    """A [`chassis_sdk.Chassis`][chassis_sdk.Chassis] (protocol A) with blocking methods.

    The same constructor options as the async class, plus ``stop_on_signals``; see
    [`chassis_sdk.sync`][chassis_sdk.sync] for the background loop, timeouts, Ctrl-C and exit.

    Example:
        ```python
        with sync.Chassis("/dev/ttyUSB0") as robot:
            robot.verify()
            print(robot.get_firmware_version())
            robot.set_velocity(0.2, 0.0, duration=1.0)
        ```
    """

    def set_wheel_speeds(
        self,
        left: float,
        right: float,
        *,
        duration: float | None = None,
        timeout: float | None = None,
    ) -> None:
        return self._call(timeout, self._device.set_wheel_speeds, left, right, duration=duration)

    def emergency_stop(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        return self._call_own(
            timeout, self._device.emergency_stop, confirm=confirm, timeout=timeout
        )

    def release_emergency_stop(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        return self._call_own(
            timeout, self._device.release_emergency_stop, confirm=confirm, timeout=timeout
        )

    def clear_faults(
        self,
        *,
        driver: bool = True,
        front_bumper: bool = True,
        rear_bumper: bool = True,
        confirm: bool = False,
        timeout: float = 1.0,
    ) -> None:
        return self._call_own(
            timeout,
            self._device.clear_faults,
            driver=driver,
            front_bumper=front_bumper,
            rear_bumper=rear_bumper,
            confirm=confirm,
            timeout=timeout,
        )

    def start_docking(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        return self._call_own(timeout, self._device.start_docking, confirm=confirm, timeout=timeout)

    def stop_docking(self, *, confirm: bool = False, timeout: float = 1.0) -> None:
        return self._call_own(timeout, self._device.stop_docking, confirm=confirm, timeout=timeout)

    def enable_telemetry(self, enabled: bool = True, *, timeout: float | None = None) -> None:
        return self._call(timeout, self._device.enable_telemetry, enabled)

    def enable_power_telemetry(self, enabled: bool = True, *, timeout: float | None = None) -> None:
        return self._call(timeout, self._device.enable_power_telemetry, enabled)

    def get_firmware_version(self, *, timeout: float | None = None) -> int:
        return self._call(timeout, self._device.get_firmware_version)

    def get_hardware_version(self, *, timeout: float | None = None) -> str:
        return self._call(timeout, self._device.get_hardware_version)

    def get_chassis_info(self, *, timeout: float | None = None) -> ChassisInfo:
        return self._call(timeout, self._device.get_chassis_info)

    def get_ship_date(self, *, timeout: float | None = None) -> datetime.date:
        return self._call(timeout, self._device.get_ship_date)

    def get_driver_status(self, *, timeout: float | None = None) -> DriverStatus:
        return self._call(timeout, self._device.get_driver_status)

    def diagnose(self, *, timeout: float | None = None) -> ChassisDiagnosis:
        return self._call(timeout, self._device.diagnose)

    def wait_for(self, predicate: Callable[[Telemetry], bool], timeout: float) -> Telemetry:
        return self._call_own(timeout, self._device.wait_for, predicate, timeout)

    def telemetry(self, *, timeout: float | None = None) -> BlockingIterator[Telemetry]:
        return self._iterate(timeout, self._device.telemetry, "telemetry")

    def power(self, *, timeout: float | None = None) -> BlockingIterator[PowerTelemetry]:
        return self._iterate(timeout, self._device.power, "power")

    @property
    def latest_telemetry(self) -> Telemetry | None:
        return self._read(lambda d: d.latest_telemetry)

    @property
    def latest_power(self) -> PowerTelemetry | None:
        return self._read(lambda d: d.latest_power)


class Board(BlockingDevice[AsyncBoard], device=AsyncBoard):
    """A [`chassis_sdk.Board`][chassis_sdk.Board] (protocol B) with blocking methods.

    The same constructor options as the async class, plus ``stop_on_signals``; see
    [`chassis_sdk.sync`][chassis_sdk.sync].

    Example:
        ```python
        with sync.Board("/dev/ttyUSB0") as board:
            board.set_led(True)
            for sample in board.imu():
                print(sample.accel)
                break
        ```
    """

    def set_led(self, on: bool, *, timeout: float | None = None) -> bool:
        return self._call(timeout, self._device.set_led, on)

    def get_led(self, *, timeout: float | None = None) -> bool:
        return self._call(timeout, self._device.get_led)

    def set_buzzer(self, on: bool, *, timeout: float | None = None) -> bool:
        return self._call(timeout, self._device.set_buzzer, on)

    def get_buzzer(self, *, timeout: float | None = None) -> bool:
        return self._call(timeout, self._device.get_buzzer)

    def set_motor_pwm(self, motor: int, pwm: int, *, timeout: float | None = None) -> None:
        return self._call(timeout, self._device.set_motor_pwm, motor, pwm)

    def set_servo(self, servo: int, angle: float, *, timeout: float | None = None) -> None:
        return self._call(timeout, self._device.set_servo, servo, angle)

    def diagnose(self, *, timeout: float | None = None) -> Diagnosis:
        return self._call(timeout, self._device.diagnose)

    def imu(self, *, timeout: float | None = None) -> BlockingIterator[ImuSample]:
        return self._iterate(timeout, self._device.imu, "imu")

    def velocity(self, *, timeout: float | None = None) -> BlockingIterator[VelocityFeedback]:
        return self._iterate(timeout, self._device.velocity, "velocity")

    def battery(self, *, timeout: float | None = None) -> BlockingIterator[BatteryReading]:
        return self._iterate(timeout, self._device.battery, "battery")

    def logs(self, *, timeout: float | None = None) -> BlockingIterator[str]:
        return self._iterate(timeout, self._device.logs, "logs")

    @property
    def latest_imu(self) -> ImuSample | None:
        return self._read(lambda d: d.latest_imu)

    @property
    def latest_velocity(self) -> VelocityFeedback | None:
        return self._read(lambda d: d.latest_velocity)

    @property
    def latest_battery(self) -> BatteryReading | None:
        return self._read(lambda d: d.latest_battery)


_classes: dict[type[Device[Any, Any]], type[BlockingDevice[Any]]] = {
    AsyncChassis: Chassis,
    AsyncBoard: Board,
}


def blocking_class(device: str | type[Device[Any, Any]]) -> type[BlockingDevice[Any]]:
    """The blocking class of a device: a registered device's name (``"chassis"``,
    ``"board"``, or one an installed package adds) or its async class. For a device
    without a typed class here, one is made from the async class (every member Any).

    Raises:
        ValueError: No such device.
        TypeError: ``device`` is neither a name nor a device class.
    """
    if isinstance(device, str):
        device = profile(device).device
    if not (isinstance(device, type) and issubclass(device, Device)):
        raise TypeError(f"device must be a device name or a Device class, got {device!r}")
    found = _classes.get(device)
    if found is None:
        found = type(device.__name__, (BlockingDevice,), {}, device=device)
        _classes[device] = found
    return found


def open(  # the module's verb, as io.open
    device: str | type[Device[Any, Any]],
    port: str,
    *,
    timeout: float | None = None,
    **options: Any,
) -> BlockingDevice[Any]:
    """Open a device by name or class, blocking: ``sync.open("chassis", port)``.

    Returns the opened blocking device (a context manager too). The options are the
    constructor's.

    Raises:
        ValueError: No such device, or a bad option.
        PortOpenError: The port cannot be opened.
    """
    return blocking_class(device)(port, **options).open(timeout=timeout)


# --- simulators --------------------------------------------------------------------------------


class Simulator:
    """A built-in simulator (`chassis_sdk.sim`) served from a background loop, for
    scripts and notebooks without hardware::

        with sync.Simulator("chassis") as sim, sync.Chassis(sim.port) as robot:
            robot.set_velocity(0.3, 0.0)

    Args:
        device: A registered device's name.
        tcp_port: Serve on ``socket://127.0.0.1:PORT`` (0: any free port) instead of a pty.

    Raises:
        ValueError: No such device.
    """

    def __init__(self, device: str = "chassis", *, tcp_port: int | None = None) -> None:
        self.server: SimulatorServer = simulator(device, tcp_port=tcp_port)
        self._loop: _Loop | None = None
        self._finalizer: weakref.finalize[Any, Any] | None = None

    @property
    def port(self) -> str:
        """What to pass to the device (see ``SimulatorServer.port``)."""
        return self.server.port

    @property
    def firmware(self) -> Any:
        """The firmware model (its state changes in the simulator's loop thread)."""
        return self.server.firmware

    @property
    def portal(self) -> BlockingPortal:
        """The anyio portal into the simulator's loop (``sim.portal.call(sim.server.unplug)``).

        Raises:
            RuntimeError: Not running.
        """
        if self._loop is None:
            raise RuntimeError("the simulator is not running")
        return self._loop.portal

    def open(self) -> Self:
        """Start serving."""
        if self._loop is not None:
            raise RuntimeError("the simulator is already running")
        loop = _Loop("chassis_sdk.sync simulator")
        try:
            loop.run(5.0, self.server.start, "start the simulator")
        except BaseException:
            loop.stop()
            raise
        self._loop = loop
        self._finalizer = weakref.finalize(self, _stop_simulator, loop, self.server)
        return self

    def close(self) -> None:
        """Stop serving (the device sees an unplug). Safe to call more than once."""
        loop, self._loop = self._loop, None
        if loop is not None and self._finalizer is not None:
            self._finalizer.detach()
            _stop_simulator(loop, self.server)

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _stop_simulator(loop: _Loop, server: SimulatorServer) -> None:
    try:
        loop.run(5.0, server.stop, "stop the simulator")
    finally:
        loop.stop()


# The typed twins above take the async docstrings (and their note) when they are made;
# check once here that nothing was lost, so a renamed async method fails at import.
for _cls in (Chassis, Board):
    for _name, _ in _public_members(_cls._async_class):
        if _name not in _OWN and not hasattr(_cls, _name):  # pragma: no cover
            raise AssertionError(f"sync.{_cls.__name__} has no {_name}")
del _cls, _name
