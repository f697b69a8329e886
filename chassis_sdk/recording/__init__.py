"""Recording: a device's session both ways, to JSON lines or MCAP, and back.

* :mod:`.writers`: the recorders (:class:`~.writers.JsonlRecording`,
  :class:`~.writers.McapRecording` with Foxglove JSON schemas, and the sink they and
  the live Foxglove server share); the ``record=`` option of every device opens one;
* :mod:`.capture`: recording a port passively, reading captures, replaying them on a
  pty or into a device, detecting the device in a capture;
* :mod:`.export`: a capture as CSV tables; :mod:`.columns`: a capture decoded into
  arrays (for plots of hours of frames).

Recorders see a device only through its public observation API
(:meth:`~chassis_sdk.core.device.Device.add_tap`, :meth:`~chassis_sdk.core.device.Device.listen`,
:meth:`~chassis_sdk.core.device.Device.listen_states`).
"""

from __future__ import annotations

from ..core.device import set_recorder
from .writers import JsonlRecording, McapRecording, Recording, open_recording

__all__ = ["JsonlRecording", "McapRecording", "Recording", "open_recording"]

set_recorder(open_recording)
