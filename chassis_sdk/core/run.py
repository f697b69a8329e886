"""``chassis_sdk.run``: ``asyncio.run`` for programs that drive a robot.

Why it exists
-------------
Ctrl-C cancels the main task under ``asyncio.run``, so every ``async with Chassis(...)``
unwinds and writes its zero-velocity frame. SIGTERM, what systemd, Docker and
Kubernetes send to stop a service, and SIGHUP (the terminal went away) kill a plain
Python process on the spot: nothing is written and only the firmware's own timeout
stops the wheels. [`run`][chassis_sdk.run] turns both into the same cancellation as Ctrl-C.
"""

from __future__ import annotations

import asyncio
import importlib
import os
import select
import signal
import sys
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from ..errors import ChassisError, RequestTimeoutError, install_hint

__all__ = ["run"]

T = TypeVar("T")

#: ``CHASSIS_SDK_LOOP=asyncio`` keeps :func:`run` on asyncio's own loop.
ENV_LOOP = "CHASSIS_SDK_LOOP"
#: Signals that cancel the main task (SIGINT is asyncio.Runner's own).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
#: The exit status of a program ended by Ctrl-C (128 + SIGINT), as a shell reports it.
INTERRUPTED = 128 + signal.SIGINT
#: A cancellation is repeated this often, this many times, while the task runs on.
RECANCEL_AFTER = 1.0
RECANCELS = 10


def run(
    main: Coroutine[Any, Any, T],
    *,
    debug: bool | None = None,
    one_line_errors: bool = False,
    uvloop: bool | None = None,
) -> T:
    """Run ``main`` to completion in a new event loop, like `asyncio.run`, with
    SIGTERM and SIGHUP cancelling it the way Ctrl-C does.

    On the first such signal the main task is cancelled: every ``async with`` block
    unwinds, so each device writes zero velocity and closes its port, and then this
    function raises ``SystemExit(128 + signal number)`` (143 for SIGTERM), the exit
    status a shell reports for a process ended by that signal. A second signal, while
    the first is still unwinding, ends the process at once (the default action).
    Ctrl-C raises `KeyboardInterrupt` after the same unwinding, as under
    `asyncio.run`.

    Example:
        ```python
        import chassis_sdk

        async def main() -> None:
            async with chassis_sdk.Chassis("/dev/ttyUSB0") as robot:
                ...

        chassis_sdk.run(main())
        ```

    Args:
        main: The program's main coroutine.
        debug: asyncio debug mode, as for `asyncio.run`.
        one_line_errors: For scripts an operator runs: a [`ChassisError`][chassis_sdk.ChassisError]
            (no such port, nothing answering, another device on the port, the link
            lost...) ends the program with its message on one line of stderr, named
            after the script, and exit status 1 (2 for a timeout: every timeout the
            SDK raises is one, ``wait_for`` and ``wait_connected`` included), instead
            of a traceback; Ctrl-C ends it quietly with exit status 130 (no
            ``KeyboardInterrupt`` traceback). Standard output closed by its reader
            (``| head``) ends it quietly with exit status 0, as ``chassis-sdk`` does.
            The robot has been stopped by then, as on any exit.
        uvloop: Run on `uvloop <https://github.com/MagicStack/uvloop>`_ (extra
            ``uvloop``): ``None`` (default) when it is installed, unless the
            environment says ``CHASSIS_SDK_LOOP=asyncio``; ``True`` requires it;
            ``False`` never. It spends less CPU on every wake-up (see Figures).

    Returns:
        What ``main`` returned.

    Raises:
        SystemExit: ``main`` was cancelled by SIGTERM or SIGHUP, or (with
            ``one_line_errors``) failed with a ``ChassisError``, was interrupted
            by Ctrl-C, or lost the reader of its standard output.
        KeyboardInterrupt: Ctrl-C, without ``one_line_errors`` (as under
            `asyncio.run`).
    """
    try:
        factory = loop_factory(uvloop)
    except ImportError:
        main.close()  # never to run: no "never awaited" warning
        raise
    if not one_line_errors:
        return _run(main, debug, factory)
    try:
        return _run(main, debug, factory)
    except KeyboardInterrupt:
        # Ctrl-C: the robot is stopped by now (every ``async with`` unwound); the
        # operator asked for it, so no traceback, and the status a shell gives it.
        raise SystemExit(INTERRUPTED) from None
    except RequestTimeoutError as exc:
        print(f"{_program()}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    except ChassisError as exc:
        print(f"{_program()}: {exc}", file=sys.stderr)
        raise SystemExit(1) from None
    except BrokenPipeError:
        if not _stdout_closed():  # another pipe (a socket of the program's own)
            raise
        # What is left in stdout's buffer goes nowhere, not into a second error at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise SystemExit(0) from None


def _stdout_closed() -> bool:
    """Whether standard output is a pipe whose reader has gone (``| head`` read its
    lines)."""
    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll, or stdout is not a file
        return False


async def _final_zeros() -> None:
    """Before the loop ends: wait for every device that stopped reading to take its
    final zero (each bounded by its ``close_linger``), through further cancellations
    (a second signal ends the process anyway)."""
    from .transport import wait_lingering

    while True:
        try:
            await wait_lingering()
            return
        except asyncio.CancelledError:
            continue


def _program() -> str:
    return os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "python"


def loop_factory(use_uvloop: bool | None = None) -> Callable[[], asyncio.AbstractEventLoop] | None:
    """uvloop's loop factory if it is to be used (see [`run`][chassis_sdk.run]), else ``None``.

    Raises:
        ImportError: ``use_uvloop=True`` without uvloop installed.
    """
    if use_uvloop is False:
        return None
    if use_uvloop is None and os.environ.get(ENV_LOOP, "").lower() == "asyncio":
        return None
    try:
        uvloop = importlib.import_module("uvloop")  # an optional extra: not typed here
    except ImportError:
        if use_uvloop:
            raise ImportError(f"uvloop=True needs it: {install_hint('uvloop')}") from None
        return None
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


def _run(
    main: Coroutine[Any, Any, T],
    debug: bool | None,
    factory: Callable[[], asyncio.AbstractEventLoop] | None,
) -> T:
    received: list[int] = []

    async def guarded() -> T:
        loop = asyncio.get_running_loop()
        task = asyncio.current_task()
        assert task is not None

        def on_signal(signum: int) -> None:
            received.append(signum)
            for sig in installed:  # a second signal takes the default action
                loop.remove_signal_handler(sig)
            cancel(f"received {signal.Signals(signum).name}", RECANCELS)

        def cancel(why: str, again: int) -> None:
            # asyncio.wait_for before Python 3.12 loses a cancellation that arrives as
            # its future completes (gh-86296), and libraries use it everywhere (aiomqtt
            # on every publish): the program would go on as if never asked to stop.
            # Until the task is done, ask again; closing a device is shielded, so a
            # second request cannot cut its zero frame short.
            if not task.done():
                task.cancel(why)
                if again:
                    loop.call_later(RECANCEL_AFTER, cancel, why, again - 1)

        installed: list[signal.Signals] = []
        for sig in STOP_SIGNALS:
            try:
                loop.add_signal_handler(sig, on_signal, sig)
            except (NotImplementedError, RuntimeError, ValueError):
                continue  # not the main thread, or a platform without signals
            installed.append(sig)
        try:
            return await main
        finally:
            await _final_zeros()
            for sig in installed:
                loop.remove_signal_handler(sig)

    with asyncio.Runner(debug=debug, loop_factory=factory) as runner:
        try:
            return runner.run(guarded())
        except asyncio.CancelledError:
            if not received:
                raise
    raise SystemExit(128 + received[0])
