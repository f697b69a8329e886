"""What every device's ``monitor`` view shares: the three forms (a live table on a
terminal through rich, plain lines when piped, one JSON object per message), the link
states and the events, told the same way for every device."""

from __future__ import annotations

import abc
import collections
import json
import math
import sys
import time
from collections.abc import Callable, Coroutine
from typing import Any

import anyio

from ..core.device import Device
from ..core.plain import outbound
from .common import out

__all__ = ["LiveView"]


class LiveView(abc.ABC):
    """A monitor's view of ``device``: subclasses add their streams and ``render()``.

    Attributes:
        live: The rich ``Live`` display on a terminal, else ``None`` (piped, or
            ``as_json``, or rich missing).
        recent: The last few link changes and events, for the table.
    """

    def __init__(self, device: Device[Any, Any], port: str, as_json: bool) -> None:
        self.device = device
        self.port = port
        self.as_json = as_json
        self.recent: collections.deque[str] = collections.deque(maxlen=4)
        self.live: Any = None
        if not as_json and sys.stdout.isatty():
            try:
                from rich.live import Live

                self.live = Live(auto_refresh=False)
                self.live.start()
            except ImportError:
                pass

    def close(self) -> None:
        """End the live display (the last table stays on the screen)."""
        if self.live is not None:
            self.live.stop()

    def emit(self, kind: str, message: object, **extra: Any) -> None:
        """One JSON line: ``{"type": kind, ...the message (wall-clock stamped)...}``."""
        out(json.dumps({"type": kind, **outbound(message), **extra}))

    async def follow_states(self) -> None:
        """Tell the link as it is, then each change of it."""
        if not self.as_json and self.live is None:
            out(f"link: {self.device.connection_state.value} via {self.device.transport_backend}")
        async for state in self.device.connection_states():
            if self.as_json:
                out(json.dumps({"type": "link", "state": state.value}))
            else:
                self.recent.append(f"{time.strftime('%H:%M:%S')} link {state.value}")
                if self.live is None:
                    out(f"link: {state.value}")

    async def follow_events(self) -> None:
        """Tell each event (the link's own are told by `follow_states`)."""
        async for event in self.device.events():
            if event.kind.value.startswith("link_"):
                continue
            if self.as_json:
                self.emit("event", event)
            else:
                self.recent.append(f"{time.strftime('%H:%M:%S')} {event}")
                if self.live is None:
                    out(f"event: {event}")

    async def run(
        self,
        seconds: float | None,
        *followers: Callable[[], Coroutine[Any, Any, None]],
        lines: Callable[[], Coroutine[Any, Any, None]] | None = None,
    ) -> None:
        """Run the view for ``seconds`` (``None``: until cancelled): the device's own
        ``followers``, the link and the events, and the table on a terminal (else
        ``lines``, the piped form's printer, if the view prints on a clock)."""
        async with anyio.create_task_group() as tg:
            for follow in (*followers, self.follow_states, self.follow_events):
                tg.start_soon(follow)
            if self.live is not None:
                tg.start_soon(self.render_loop)
            elif not self.as_json:
                print("Ctrl-C to quit", file=sys.stderr)
                if lines is not None:
                    tg.start_soon(lines)
            with anyio.move_on_after(math.inf if seconds is None else seconds):
                await anyio.sleep_forever()
            tg.cancel_scope.cancel()
        self.close()

    @abc.abstractmethod
    def render(self) -> Any:
        """The table shown on a terminal."""

    async def render_loop(self) -> None:
        """Redraw the table ten times a second."""
        while True:
            self.live.update(self.render(), refresh=True)
            await anyio.sleep(0.1)

    def counters(self) -> str:
        """The link's counters, for the table's last row."""
        s = self.device.stats
        return (
            f"{s.frames} frames, {s.bytes_dropped} bytes dropped, "
            f"{s.checksum_errors} checksum errors, {s.sequence_gaps} gaps, "
            f"{s.reconnects} reconnects"
        )
