"""The controller board (protocol B): IMU, LED, buzzer, motors and servos.

* `.messages`: the typed messages and their enums;
* `.protocol`: the sans-IO codec (frames, encoder, decoders);
* `.device`: [`Board`][chassis_sdk.Board], the public API;
* `.firmware`: the sans-IO firmware model (served by `chassis_sdk.sim`);
* `.profile`: its registry entry.

``Board`` is imported on first use, so the codec loads without the runtime.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .device import Board

__all__ = ["Board"]


__getattr__, __dir__ = _lazy(__name__, {"Board": ".device"}, globals())
