"""The controller board (protocol B): IMU, LED, buzzer, motors and servos.

* :mod:`.messages`: the typed messages and their enums;
* :mod:`.protocol`: the sans-IO codec (frames, encoder, decoders);
* :mod:`.device`: :class:`Board`, the public API;
* :mod:`.firmware`: the sans-IO firmware model (served by :mod:`chassis_sdk.sim`);
* :mod:`.profile`: its registry entry.

``Board`` is imported on first use, so the codec loads without the runtime.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .device import Board

__all__ = ["Board"]


__getattr__, __dir__ = _lazy(__name__, {"Board": ".device"}, globals())
