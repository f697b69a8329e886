"""The link: one ``asyncio.Protocol`` per port, and the only module that knows which
pyserial asyncio package is in use.

pyserial-asyncio-fast (an optional extra) is preferred when installed: it writes eagerly
instead of on the next loop iteration, calls ``connection_lost`` only once the port is
really closed, and opens ``socket://`` URLs with the loop's own connection (pyserial's
socket ``close()`` sleeps 0.3 s on the event loop). Both open every URL through
``serial.serial_for_url``, so device paths, pseudo-terminals and ``socket://host:port``
work alike.
"""

from __future__ import annotations

import asyncio
import errno
import importlib
import logging
import os
import time
from collections.abc import Callable
from typing import Any, Generic, Protocol, TypeVar, cast

from .errors import PortOpenError

_BACKENDS = {
    "pyserial-asyncio-fast": "serial_asyncio_fast",
    "pyserial-asyncio": "serial_asyncio",
}


def _load_backend() -> tuple[Any, str]:
    """Prefer the maintained fork when installed; both have the same API.

    The environment variable ``CHASSIS_SDK_BACKEND`` (``pyserial-asyncio`` or
    ``pyserial-asyncio-fast``) forces one, to compare them or to rule one out.
    """
    forced = os.environ.get("CHASSIS_SDK_BACKEND")
    if forced:
        if forced not in _BACKENDS:
            raise ImportError(
                f"CHASSIS_SDK_BACKEND={forced!r}: use one of {', '.join(sorted(_BACKENDS))}"
            )
        return importlib.import_module(_BACKENDS[forced]), forced
    for name, module in _BACKENDS.items():
        try:
            return importlib.import_module(module), name
        except ImportError:  # pragma: no cover - depends on the installed extra
            continue
    raise ImportError("chassis_sdk needs pyserial-asyncio: pip install pyserial-asyncio")


_serial_asyncio, BACKEND = _load_backend()

__all__ = ["BACKEND", "Link", "open_link"]

M = TypeVar("M")


class Decoder(Protocol[M]):
    """What the link needs of a decoder."""

    def feed(self, data: bytes, timestamp: float = 0.0) -> list[M]: ...

    def reset(self) -> None: ...


class Link(asyncio.Protocol, Generic[M]):
    """Feeds received bytes to the decoder synchronously and hands each message on.

    Args:
        decoder: The protocol's decoder (kept across reconnects for its stats).
        on_messages: Called once per received chunk that decoded into messages, with
            the messages in wire order and the ``time.monotonic()`` of their arrival
            (one call per chunk, not per message: the hot path stays flat).
        on_lost: Called once when the connection is lost, with the error if any.
        logger: Hex dumps go here at DEBUG.
    """

    def __init__(
        self,
        decoder: Decoder[M],
        on_messages: Callable[[list[M], float], None],
        on_lost: Callable[[Exception | None], None],
        logger: logging.Logger,
    ) -> None:
        self._decoder = decoder
        self._on_messages = on_messages
        self._on_lost = on_lost
        self._log = logger
        self.transport: asyncio.WriteTransport | None = None
        self.closed = asyncio.get_running_loop().create_future()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.WriteTransport, transport)

    def data_received(self, data: bytes) -> None:
        now = time.monotonic()
        if self._log.isEnabledFor(logging.DEBUG):
            self._log.debug("rx %s", data.hex(" "))
        messages = self._decoder.feed(data, now)
        if messages:
            self._on_messages(messages, now)

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        if not self.closed.done():
            self.closed.set_result(None)
        self._on_lost(exc)

    def write(self, frame: bytes) -> bool:
        """Write one frame; return False if the link is not open."""
        transport = self.transport
        if transport is None or transport.is_closing():
            return False
        if self._log.isEnabledFor(logging.DEBUG):
            self._log.debug("tx %s", frame.hex(" "))
        transport.write(frame)
        return True

    async def drain(self, timeout: float) -> None:
        """Wait (at most ``timeout`` s) until every written byte has left the buffer.

        ``transport.flush()`` in pyserial-asyncio discards unsent bytes rather than
        waiting for them, so the final zero-velocity frame is waited out this way.
        """
        deadline = time.monotonic() + timeout
        while (transport := self.transport) is not None and not transport.is_closing():
            if transport.get_write_buffer_size() == 0 or time.monotonic() >= deadline:
                return
            await asyncio.sleep(0.002)

    async def aclose(self, timeout: float) -> None:
        """Close the transport and wait (bounded) until the port is really closed."""
        transport = self.transport
        if transport is not None:
            transport.close()
        if not self.closed.done():
            try:
                await asyncio.wait_for(asyncio.shield(self.closed), timeout)
            except TimeoutError:
                self._log.warning("port did not report closing within %.1f s", timeout)


def _describe_open_error(url: str, exc: BaseException) -> str:
    err = getattr(exc, "errno", None)
    text = str(exc)
    if (
        err == errno.ENOENT
        or "No such file" in text
        or ("could not open port" in text and ("[Errno 2]" in text))
    ):
        return f"could not open {url}: no such device (is it plugged in? check `ls /dev/tty*`)"
    if err == errno.EACCES or "[Errno 13]" in text or "Permission denied" in text:
        return (
            f"could not open {url}: permission denied (add yourself to the group that "
            "owns the device, usually `sudo usermod -aG dialout $USER`, then log in again)"
        )
    if err == errno.ECONNREFUSED or "Connection refused" in text or "[Errno 111]" in text:
        return f"could not open {url}: connection refused (is the server running?)"
    return f"could not open {url}: {text}"


async def open_link(
    url: str,
    baudrate: int,
    link_factory: Callable[[], Link[Any]],
) -> Link[Any]:
    """Open ``url`` (device path, pty path or ``socket://host:port``) at 8N1.

    Raises:
        PortOpenError: The port cannot be opened; the message says why and what to do.
    """
    loop = asyncio.get_running_loop()
    try:
        transport, protocol = await _serial_asyncio.create_serial_connection(
            loop, link_factory, url, baudrate=baudrate, bytesize=8, parity="N", stopbits=1
        )
    except (OSError, ValueError) as exc:
        # serial.SerialException is an OSError subclass; bad URLs raise ValueError.
        raise PortOpenError(_describe_open_error(url, exc)) from exc
    link = cast(Link[Any], protocol)
    # connection_made() is only scheduled (call_soon); the link can write from now on.
    link.connection_made(transport)
    return link
