"""Recording: a device's session both ways, to JSON lines or MCAP, and back.

* `.sink`: `FoxgloveSink`, which publishes a device's session into
  a ``foxglove.Context`` (Foxglove JSON schemas, the session's metadata); the MCAP
  recorder and the live Foxglove server share it;
* `.mcap`: `McapRecording`, the one MCAP recorder (compressed,
  flushed every second);
* `.ros2`: `Ros2Recording`, the same session as a rosbag2 MCAP file
  (ROS 2 types in CDR, with their QoS and type hashes) for ROS 2 tools, chosen with
  `rosbag`; `.ros2_types`, the ROS 2 messages it and the bridge use;
* `.jsonl`: `JsonlRecording` and the JSON-lines capture format,
  written and read;
* `open_recording` opens either by the file's name; the ``record=`` option of
  every device opens one through it;
* `.capture`: recording a port passively, reading captures, replaying them on a
  pty or into a device, detecting the device in a capture;
* `.export`: a capture as CSV tables; `.columns`: a capture decoded into
  arrays (for plots of hours of frames).

Recorders see a device only through its public observation API
([`Notifier`][chassis_sdk.core.notifier.Notifier], ``feed``, ``command_decoder``).
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
    """A device's session being written to a file (see `open_recording`)."""

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
    path: str | os.PathLike[str],
    device: Device[Any, Any],
    *,
    ros2: bool = False,
    **options: Any,
) -> Recording:
    """Start recording ``device``'s session to ``path``: an MCAP file for ``.mcap``
    (needs the ``foxglove`` extra), a JSON-lines capture for any other name; with
    ``ros2``, a rosbag2 MCAP file for ROS 2 tools (needs the ``ros2`` extra; see
    `chassis_sdk.recording.ros2`).

    Args:
        path: The file (overwritten).
        device: The device whose session this is.
        ros2: Write the ROS 2 profile (``.mcap`` only) instead of Foxglove's.
        **options: The recorder's: `McapRecording`'s, or with ``ros2``
            those of `rosbag` (``namespace``, frames, ...).

    Raises:
        ImportError: ``.mcap`` without foxglove-sdk installed (with ``ros2``: without
            cyclonedds or mcap).
        ValueError: ``ros2`` for a name that is not ``.mcap``, or a bad option.
    """
    path = Path(path)
    if ros2:
        from .ros2 import rosbag

        return rosbag(path, **options).open_recorder(device)
    if path.suffix.lower() == ".mcap":
        return McapRecording(path, device, **options)
    return JsonlRecording(path, device.port, device.baudrate, device)


set_recorder(open_recording)
