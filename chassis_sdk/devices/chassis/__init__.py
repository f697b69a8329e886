"""The chassis (protocol A): a four-wheel skid-steer base.

* :mod:`.messages`: the typed messages and their enums;
* :mod:`.protocol`: the sans-IO codec (frames, encoder, decoders);
* :mod:`.device`: :class:`Chassis`, the public API;
* :mod:`.health`: what its status words mean (events, diagnosis findings);
* :mod:`.firmware`: the firmware model and its simulator;
* :mod:`.cli`: its part of ``chassis-sdk``; :mod:`.profile`: its registry entry.
"""

from .device import Chassis

__all__ = ["Chassis"]
