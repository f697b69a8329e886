"""The close of a `Link`: a bounded drain, the stale
frames discarded, the final zero kept, and the background "linger".

`Link.aclose` hands its work to the
link's `Linger`. It gives what is on its way a moment to leave; if the device is
still not reading then, every stale frame is discarded (what the link holds, and a
serial port's kernel output queue, with ``tcflush``) **but the final zero is kept**: it
goes out at once where the flush made room (a serial port), or waits in the background
(a socket whose kernel buffer cannot be flushed, a serial line held by flow control)
for at most ``linger`` seconds after ``close()`` has returned. Whether it has left is
read from the kernel's output queue (``TIOCOUTQ`` / ``SIOCOUTQ``), polled, since that
queue has no event. The descriptors are closed once it has left or the bound has
passed, and then whatever is still held is discarded (a socket is reset, so the kernel
sends nothing stale either).

A link closing in the background is registered by port: `open_link`
of the same port waits for it (its zero must be
the last frame of that session), and `wait_lingering` lets a program end only
once every zero has left (or its bound has passed).

Each link makes its own `Linger`, which acts on the link only through `Closable`, the
hooks a link offers its close (``drain``, ``keep_only_the_zero``, ``drop_held``,
``release_write_fd``...); the link remains the one object its owner talks to.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import logging
import socket
import struct
import termios
from typing import Protocol

import anyio

__all__ = ["CLOSE_GRACE", "CLOSE_WAIT", "Closable", "Linger", "lingering", "wait_lingering"]

#: How long a port (or a socket's peer) closing by itself may take before a lingering
#: close goes on in the background, and before a given-up close is taken as done.
CLOSE_GRACE = 0.1
CLOSE_WAIT = 1.0
#: ``SO_LINGER`` on, 0 s: ``close()`` resets the connection and drops unsent data.
_RESET = struct.pack("ii", 1, 0)
#: How often a lingering link looks whether its final zero has left the kernel.
_LINGER_POLL = 0.005
#: Links closing in the background (their final zero not yet out), by port: a program
#: that reopens a port waits for its earlier link to finish, and :func:`wait_lingering`
#: lets a program end only once every zero has left (or its bound has passed).
_lingering: dict[tuple[asyncio.AbstractEventLoop, str], Linger] = {}


def lingering(loop: asyncio.AbstractEventLoop, url: str) -> Linger | None:
    """The close still going on in the background for port ``url`` on ``loop``, if any."""
    return _lingering.get((loop, url))


async def wait_lingering(timeout: float | None = None) -> None:
    """Wait until no link is closing in the background any more (every final zero has
    left, or its ``close_linger`` bound has passed), at most ``timeout`` seconds.

    [`chassis_sdk.run`][chassis_sdk.run] calls this before the program ends; under a plain
    `asyncio.run`, a link still lingering when the loop ends discards its zero
    (nothing stale is ever sent either way).
    """
    loop = asyncio.get_running_loop()
    with anyio.fail_after(timeout):
        while mine := [closing for (lp, _), closing in _lingering.items() if lp is loop]:
            await mine[0].lingered()


class Closable(Protocol):
    """What a link offers its close (`chassis_sdk.core.transport.Link` has it)."""

    @property
    def transport(self) -> asyncio.WriteTransport | None: ...
    @property
    def url(self) -> str: ...
    @property
    def closed(self) -> asyncio.Future[None]: ...
    @property
    def discarded(self) -> int: ...
    @property
    def loop(self) -> asyncio.AbstractEventLoop: ...
    @property
    def log(self) -> logging.Logger: ...
    @property
    def write_fd(self) -> int | None: ...
    @property
    def finished(self) -> bool: ...
    @property
    def holds_zero(self) -> bool: ...
    async def drain(self, timeout: float) -> bool: ...
    def is_flushed(self) -> bool: ...
    def mark_finished(self) -> None: ...
    def stop_receiving(self) -> None: ...
    def discard_partial(self) -> None: ...
    def keep_only_the_zero(self, flushed: bool) -> None: ...
    def count_lost(self) -> None: ...
    def drop_held(self) -> None: ...
    def release_write_fd(self) -> None: ...


class Linger:
    """Closes one link (see the module docstring); made by the link, used through its
    `aclose` and
    `lingered`."""

    def __init__(self, link: Closable) -> None:
        self._link = link
        self._task: asyncio.Task[None] | None = None  # the background close, once handed over

    # --- the kernel's output queue ------------------------------------------------------

    def _kernel_pending(self) -> int:
        """Bytes the kernel still holds: not yet sent (a serial port's driver) or not
        yet acknowledged by the peer (a TCP socket): ``TIOCOUTQ`` / ``SIOCOUTQ``; 0
        where the driver cannot tell (a pty always says 0).

        Closing a tty with bytes pending blocks in the kernel (``closing_wait``, 30 s
        by default) or discards them; closing a socket with received bytes unread
        (telemetry keeps coming) resets it, and the kernel drops what the peer has not
        acknowledged, the final zero with it. Once this is 0, nothing can be lost.
        """
        link = self._link
        fd = link.write_fd
        if fd is None and link.transport is not None:
            sock = link.transport.get_extra_info("socket")
            fd = sock.fileno() if sock is not None else None
        if fd is None or fd < 0:
            return 0
        try:
            buf = fcntl.ioctl(fd, termios.TIOCOUTQ, b"\0\0\0\0")
        except OSError:
            return 0
        pending: int = struct.unpack("i", buf)[0]
        return pending

    def _is_out(self) -> bool:
        """Everything written has left: the link holds nothing and neither does the
        kernel."""
        return self._link.is_flushed() and not self._kernel_pending()

    async def _until_out(self, limit: float) -> bool:
        """Wait (at most ``limit`` s) until everything written has left; return whether
        it has."""
        link = self._link
        with anyio.move_on_after(limit):
            await link.drain(limit)
            while self._kernel_pending() and link.transport is not None:  # noqa: ASYNC110
                await anyio.sleep(_LINGER_POLL)  # (the kernel's queue has no event)
        return self._is_out()

    def _flush_output(self) -> bool:
        """Discard a serial port's kernel output queue; False for a socket (whose
        kernel buffer cannot be flushed)."""
        wfd = self._link.write_fd
        if wfd is None:
            return False
        with contextlib.suppress(OSError, termios.error):
            termios.tcflush(wfd, termios.TCOFLUSH)
        return True

    # --- discarding and closing ---------------------------------------------------------

    def _discard_stale(self) -> None:
        """The device is not reading and the link is closing: discard every frame still
        held (and, for a serial port, the kernel's output queue), but keep the final
        zero, whole, and send it at once where that made room."""
        link = self._link
        before = link.discarded
        link.discard_partial()
        flushed = self._flush_output()
        # The zero, held, or (a serial port) flushed from the kernel with the rest, even
        # part sent, is held again whole, the last frame the device will get. A device
        # that took the head of a frame before the flush resynchronises on it.
        link.keep_only_the_zero(flushed)
        stale = link.discarded - before
        link.log.log(
            logging.WARNING if stale else logging.INFO,
            "the device is not reading; discarded %d stale frame(s) on closing%s",
            stale,
            ", kept the final zero" if link.holds_zero else "",
        )

    async def _finish(self, wait: float) -> bool:
        """Close a port whose bytes have all left; return whether it is closed.

        A socket is half-closed and read on until its peer closes too (at most
        ``wait`` seconds here): closing a socket with received bytes unread (telemetry
        keeps coming) resets it, and a peer reading through a buffered stream (asyncio's
        own) loses on a reset what it had not read yet, the final zero with it.
        """
        link = self._link
        transport = link.transport
        if transport is None or transport.is_closing():
            return True
        link.mark_finished()
        link.stop_receiving()  # what comes now is of no one's use
        if link.write_fd is not None or not transport.can_write_eof():
            transport.close()
            return True
        transport.write_eof()
        with anyio.move_on_after(wait):
            await asyncio.shield(link.closed)  # a future of the transport's: never cancelled
        return link.closed.done()

    def _give_up(self) -> None:
        """Close now, discarding whatever has not left: nothing stale may reach the
        device afterwards (a socket is reset, so its kernel buffer is dropped too)."""
        link = self._link
        transport = link.transport
        if transport is None:
            return
        link.mark_finished()
        if not self._is_out():
            link.drop_held()
            if not self._flush_output():
                if transport.get_write_buffer_size():
                    link.count_lost()  # what asyncio's transport still held
                sock = transport.get_extra_info("socket")
                if sock is not None:
                    with contextlib.suppress(OSError):
                        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _RESET)
        transport.abort()

    async def aclose(self, timeout: float, linger: float) -> None:
        """`Link.aclose`, which see."""
        link = self._link
        try:
            transport = link.transport
            if transport is not None and not transport.is_closing() and not link.finished:
                # A moment for what is on its way (the kernel of a healthy line empties
                # in a millisecond or two), then what is still held is stale.
                if not await self._until_out(CLOSE_GRACE):
                    self._discard_stale()
                if await self._until_out(CLOSE_GRACE):
                    if not await self._finish(CLOSE_GRACE):  # a peer slow to close
                        if linger > 0:
                            self._hand_over(linger)
                            return
                        transport.close()
                elif linger > 0:
                    self._hand_over(linger)
                    return
                else:
                    self._give_up()
            await self._wait_closed(timeout)
        except BaseException:  # cancelled (the loop is ending): never leave it open
            if self._task is None:
                self._give_up()
                link.release_write_fd()
            raise

    def _hand_over(self, linger: float) -> None:
        """Go on closing in the background: the caller's close() returns now."""
        link = self._link
        # Nobody is listening any more (a recording is closed once close() returns).
        link.stop_receiving()
        _lingering[link.loop, link.url] = self  # an open of this port from now on waits
        self._task = asyncio.ensure_future(self._linger_then_close(linger))

    async def lingered(self) -> None:
        """Wait until the link's background close (if any) is over; a cancellation
        stops the wait, not the close."""
        link = self._link
        task = self._task
        if task is not None and not task.done():
            await asyncio.wait((task,))
        if _lingering.get((link.loop, link.url)) is self:  # a task that never ran
            del _lingering[link.loop, link.url]
            self._give_up()
            link.release_write_fd()

    async def _wait_closed(self, timeout: float) -> None:
        link = self._link
        if not link.closed.done():
            try:
                with anyio.fail_after(timeout):
                    await asyncio.shield(link.closed)
            except TimeoutError:
                if link.transport is not None:  # stuck: never leave it open
                    link.log.warning("port did not close within %.1f s; aborted", timeout)
                    self._give_up()
                else:
                    link.log.warning("port did not report closing within %.1f s", timeout)
        link.release_write_fd()

    async def _linger_then_close(self, bound: float) -> None:
        """Hold the port open (in the background) until the final zero has left and, for
        a socket, the peer has closed after it, or ``bound`` seconds have passed."""
        link = self._link
        loop = link.loop
        link.log.info("the device is not reading; the final zero waits up to %g s", bound)
        deadline = loop.time() + bound
        try:
            if not link.finished:
                if await self._until_out(bound):
                    await self._finish(max(deadline - loop.time(), 0.0))
                elif link.transport is not None:
                    link.log.warning(
                        "the device did not read for %g s after closing; what had not "
                        "left is discarded",
                        bound,
                    )
                    self._give_up()
            elif not link.closed.done():  # half-closed: the peer has it all; let it close
                with anyio.move_on_after(max(deadline - loop.time(), 0.0)):
                    await asyncio.shield(link.closed)
            transport = link.transport
            if transport is not None and not transport.is_closing():
                link.log.info("the peer kept the connection open after the final zero")
                transport.close()
            await self._wait_closed(CLOSE_WAIT)
        except BaseException:  # cancelled (the loop is ending): nothing stale, ever
            self._give_up()
            link.release_write_fd()
            raise
        finally:
            if _lingering.get((loop, link.url)) is self:
                del _lingering[loop, link.url]
