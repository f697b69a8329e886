"""A device's session recorded to an MCAP file, by the Foxglove sink
([`chassis_sdk.recording.sink`][chassis_sdk.recording.sink]: see it for the topics).

What a hard kill loses: the MCAP writer finishes a chunk and flushes it to the file
every ``flush_interval`` seconds (1 s), so ``kill -9`` or a power cut loses at most the
last second, and the file lacks its summary (``chassis-sdk replay``, ``export`` and the
``mcap`` tools' ``recover`` read such a file up to where it stops). A normal exit,
an exception, Ctrl-C and SIGTERM (via [`chassis_sdk.run`][chassis_sdk.run]) close it properly.
Every MCAP recording goes through `McapRecording`: an application's
``record=``, ``chassis-sdk record`` and ``chassis-sdk serve --record``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .jsonl import FLUSH_INTERVAL
from .sink import FoxgloveSink, _needs_foxglove, session_metadata

if TYPE_CHECKING:
    import foxglove

    from ..core.device import Device

__all__ = ["FLUSH_INTERVAL", "McapRecording"]


class McapRecording:
    """A session written to an MCAP file by a `FoxgloveSink`; see the module
    docstring for what it holds and what a hard kill can lose.

    Args:
        path: The file (overwritten).
        device: The device whose session this is.
        flush_interval: Seconds between two flushes of the file.
        metadata: Added to the `session_metadata` record.
        context: The ``foxglove.Context`` to publish in (default: a new one). Give a
            live server's, and the recording's `sink` is the server's too: one
            sink, whose every message both the file and the server get.
    """

    def __init__(
        self,
        path: Path,
        device: Device[Any, Any],
        *,
        flush_interval: float = FLUSH_INTERVAL,
        metadata: dict[str, str] | None = None,
        context: foxglove.Context | None = None,
    ) -> None:
        try:
            import foxglove
            from foxglove.mcap import MCAPCompression, MCAPWriteOptions
        except ImportError:
            raise _needs_foxglove("recording to MCAP") from None
        self.path = path
        self._flush_interval = flush_interval
        self._last_flush = time.monotonic()
        if context is None:
            context = foxglove.Context()
        options = MCAPWriteOptions(compression=MCAPCompression.Zstd, profile="")
        self._writer = foxglove.open_mcap(
            path, allow_overwrite=True, context=context, writer_options=options
        )
        info = session_metadata(device)
        info.update(metadata or {})
        self._writer.write_metadata("chassis_sdk", info)
        self.sink = FoxgloveSink(context, device, after_log=self._maybe_flush)
        self.sink.attach()
        self._closed = False

    def _maybe_flush(self, now: float) -> None:
        if now - self._last_flush >= self._flush_interval:
            self._last_flush = now
            self._writer.flush()

    def rx(self, data: bytes, now: float) -> None:
        self.sink.rx(data, now)

    def tx(self, data: bytes, now: float) -> None:
        self.sink.tx(data, now)

    def link_state(self, state: str, now: float) -> None:
        self.sink.link_state(state, now)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.sink.detach()
            self._writer.close()
