"""Recording: a device's session both ways, to JSON lines or MCAP, and back.

* :mod:`.sink`: :class:`~.sink.FoxgloveSink`, which publishes a device's session into
  a ``foxglove.Context`` (Foxglove JSON schemas, the session's metadata); the MCAP
  recorder and the live Foxglove server share it;
* :mod:`.mcap`: :class:`~.mcap.McapRecording`, the one MCAP recorder (compressed,
  flushed every second);
* :mod:`.jsonl`: :class:`~.jsonl.JsonlRecording` and the JSON-lines capture format,
  written and read;
* :func:`open_recording` opens either by the file's name; the ``record=`` option of
  every device opens one through it;
* :mod:`.capture`: recording a port passively, reading captures, replaying them on a
  pty or into a device, detecting the device in a capture;
* :mod:`.export`: a capture as CSV tables; :mod:`.columns`: a capture decoded into
  arrays (for plots of hours of frames).

Recorders see a device only through its public observation API
(:class:`~chassis_sdk.core.notifier.Notifier`, ``feed``, ``command_decoder``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from ..core.device import set_recorder
from .jsonl import JsonlRecording
from .mcap import McapRecording

if TYPE_CHECKING:
    from ..core.device import Device

__all__ = ["JsonlRecording", "McapRecording", "Recording", "open_recording"]


class Recording(Protocol):
    """A device's session being written to a file (see :func:`open_recording`)."""

    path: Path

    def rx(self, data: bytes, now: float) -> None:
        """Bytes arrived at ``now`` (``time.monotonic()``)."""

    def tx(self, data: bytes, now: float) -> None:
        """The frame ``data`` began to leave at ``now``."""

    def link_state(self, state: str, now: float) -> None:
        """The link went to ``state``."""

    def close(self) -> None:
        """Finish the file (safe to call twice)."""


def open_recording(
    path: str | os.PathLike[str], device: Device[Any, Any], **mcap_options: Any
) -> Recording:
    """Start recording ``device``'s session to ``path``: an MCAP file for ``.mcap``
    (needs the ``foxglove`` extra), a JSON-lines capture for any other name.

    Raises:
        ImportError: ``.mcap`` without foxglove-sdk installed.
    """
    path = Path(path)
    if path.suffix.lower() == ".mcap":
        return McapRecording(path, device, **mcap_options)
    return JsonlRecording(path, device.port, device.baudrate, device)


set_recorder(open_recording)
