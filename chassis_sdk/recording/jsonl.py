"""JSON-lines captures: the format, written and read here only.

A capture is a JSON-lines file: a header line ``{"capture": 1, "port": ...,
"baudrate": ..., "started": ...}``, then one line per chunk read, ``{"t": seconds since
the start, "data": hex}``, one per frame the host wrote, ``{"t": ..., "tx": hex}``, and
a line ``{"t": ..., "event": "disconnected"}`` (or ``"reconnected"``) where the link
dropped or came back. Plain text, so captures can be diffed, trimmed and attached to
bug reports; the raw bytes both ways, from which everything else can be decoded again.

What a hard kill loses: the file is written through a buffer and flushed to the file
when the header is written and then at least once every `FLUSH_INTERVAL` (1 s) while
lines come, so ``kill -9`` or a power cut loses at most the last second (before, a
kill two seconds in could leave an empty file). A file cut in the middle of a line is
read up to the line before it.
"""

from __future__ import annotations

import datetime
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from ..core.notifier import Notifier

if TYPE_CHECKING:
    from ..core.device import Device

__all__ = ["FLUSH_INTERVAL", "JsonlRecording", "read_jsonl"]

#: The most time (seconds) a line of a capture waits in the buffer before it is flushed
#: to the file: a JSON-lines capture's, and an MCAP recording's chunk (recording.mcap).
FLUSH_INTERVAL = 1.0

#: The readers' logger (a capture cut short is a warning the commands show).
_log = logging.getLogger("chassis_sdk.recording.capture")
#: Files found cut in the middle of a line, warned about once.
_CUT: set[Path] = set()


class JsonlRecording:
    """A session written as a JSON-lines capture (the format: see the module docstring):
    the bytes received (``{"t", "data"}``), the frames written (``{"t", "tx"}``) and
    the link's drops (``{"t", "event"}``), ``t`` in seconds since the start.

    Args:
        path: The file (overwritten).
        port: For the header.
        baudrate: For the header.
        device: The device whose links to tap (``None``: the caller feeds `rx`).
    """

    def __init__(
        self,
        path: Path,
        port: str,
        baudrate: int,
        device: Device[Any, Any] | None = None,
    ) -> None:
        self.path = path
        self._start = self._flushed = time.monotonic()
        # Small buffered local writes (a thread per chunk would cost more), flushed at
        # least once a second: what a hard kill can lose is bounded.
        self._file: IO[str] = path.open("w", encoding="utf-8")
        self._line(
            {
                "capture": 1,
                "port": port,
                "baudrate": baudrate,
                "started": datetime.datetime.now(datetime.UTC).isoformat(),
            }
        )
        self.flush()  # the header at once: a file killed early is still a capture
        self._notifier: Notifier | None = None
        self._up = True
        if device is not None:
            self._notifier = Notifier(device)
            self._notifier.add_tap(self)
            self._notifier.listen_states(self._on_state)

    def _line(self, item: dict[str, object]) -> None:
        self._file.write(json.dumps(item) + "\n")
        if time.monotonic() - self._flushed >= FLUSH_INTERVAL:
            self.flush()

    def flush(self) -> None:
        """Write what the buffer holds to the file now (a recorder that goes quiet
        calls it, so the last lines do not wait for the next one)."""
        self._flushed = time.monotonic()
        if not self._file.closed:
            self._file.flush()

    def _t(self, now: float) -> float:
        return round(now - self._start, 6)

    def rx(self, data: bytes, now: float) -> None:
        self._line({"t": self._t(now), "data": data.hex()})

    def tx(self, data: bytes, now: float) -> None:
        self._line({"t": self._t(now), "tx": data.hex()})

    def link_state(self, state: str, now: float) -> None:
        up = state in ("connected", "stale")
        if up != self._up:  # only drops and comebacks are lines of a capture
            self._up = up
            self._line({"t": self._t(now), "event": "reconnected" if up else "disconnected"})

    def _on_state(self, state: Any) -> None:
        if state.value != "disconnected":  # close() is not a drop
            self.link_state(str(state.value), time.monotonic())

    def close(self) -> None:
        if self._file.closed:
            return
        if self._notifier is not None:
            self._notifier.close()
            self._notifier = None
        self._file.close()


def read_jsonl(path: str | Path, *, sent: bool = False) -> Iterator[tuple[float, bytes]]:
    """Yield ``(seconds since start, bytes)`` for each chunk of a JSON-lines capture:
    received (``"data"`` lines), or with ``sent`` the frames the host wrote (``"tx"``).

    Raises:
        ValueError: The file is not a capture, or a line is not a capture line.
    """
    key = "tx" if sent else "data"
    with Path(path).open(encoding="utf-8") as f:
        try:
            header: str | None = f.readline(1 << 16)
        except UnicodeDecodeError:
            header = None
        if header == "":
            raise ValueError(
                f"{path} is empty: no capture was written to it (a recorder killed "
                "before its first flush, or a file made by something else)"
            )
        if header is None or not _header_ok(header):
            raise ValueError(f"not a chassis-sdk capture (neither JSON lines nor MCAP): {path}")
        for n, line in enumerate(f, start=2):
            if not line.strip():
                continue
            try:
                t, field, value = _capture_line(line)
                if field == key:
                    yield t, bytes.fromhex(value)
            except (ValueError, KeyError, TypeError):
                if not line.endswith("\n"):  # the last line, cut by a hard kill
                    if Path(path).resolve() not in _CUT:  # once per file, however often read
                        _CUT.add(Path(path).resolve())
                        _log.warning("%s ends in the middle of a line: read up to there", path)
                    return
                raise ValueError(f"{path}:{n}: not a capture line") from None


def _header_ok(line: str) -> bool:
    """Whether ``line`` is a capture's first line (``{"capture": 1, ...}``)."""
    try:
        return bool(json.loads(line).get("capture") == 1)
    except (ValueError, AttributeError):
        return False


_FIELDS = ("data", "tx", "event")


def _capture_line(line: str) -> tuple[float, str, str]:
    """``(t, field, value)`` of a capture line: ``{"t": 1.5, "data": "hex"}``, its
    ``"tx"`` and ``"event"`` kinds. Lines as this module writes them are split as text
    (a quarter of a replay's time went to ``json.loads``); anything else is parsed as
    JSON."""
    if line.startswith('{"t": '):
        t_text, comma, rest = line[6:].partition(', "')
        field, colon, value = rest.partition('": "')
        end = value.rstrip().removesuffix('"}')
        if comma and colon and field in _FIELDS and '"' not in end and len(end) < len(value):
            return float(t_text), field, end
    item = json.loads(line)
    for field in _FIELDS:
        if field in item:
            return float(item["t"]), field, str(item[field])
    raise ValueError("not a capture line")
