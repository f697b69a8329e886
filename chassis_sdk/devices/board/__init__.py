"""The controller board (protocol B): IMU, LED, buzzer, motors and servos.

* :mod:`.messages`: the typed messages and their enums;
* :mod:`.protocol`: the sans-IO codec (frames, encoder, decoders);
* :mod:`.device`: :class:`Board`, the public API;
* :mod:`.firmware`: the firmware model and its simulator;
* :mod:`.cli`: its part of ``chassis-sdk``; :mod:`.profile`: its registry entry.
"""

from .device import Board

__all__ = ["Board"]
